//! The spacing bounds of DESIGN §1 as plain scalar functions, in f64. Each
//! returns `None` where nothing bounds the spacing (a flat scene for MMDS, no
//! occlusion, sky only), never an infinity, a NaN or a negative number.

/// Anything above this is "unbounded": a spacing of a million kilometres is a
/// division by a vanishing quantity, not an answer.
pub const SPACING_CAP_M: f64 = 1e9;

#[inline]
fn bounded(x: f64) -> Option<f64> {
    (x.is_finite() && x > 0.0 && x <= SPACING_CAP_M).then_some(x)
}

/// Disparity gain `f·cos φ`: pixels of disparity per metre of baseline per
/// 1/m of inverse depth, for a baseline along track (DESIGN: `b⊥ = b·cos φ`).
#[inline]
pub fn disparity_gain_px(focal_px: f64, pitch_rad: f64) -> f64 {
    (focal_px * pitch_rad.cos()).abs()
}

/// MMDS (Chai et al.): `b = 2·Δv / (f·cos φ·(w_max − w_min)·c_tex)`.
pub fn mmds_m(gain_px: f64, delta_w_per_m: f64, c_tex: f64, delta_v_px: f64) -> Option<f64> {
    let denom = gain_px * delta_w_per_m * c_tex;
    if denom.is_nan() || denom <= 0.0 {
        return None;
    }
    bounded(2.0 * delta_v_px / denom)
}

/// SSPA (Gilliam et al.): `b = 2 / (f·cos φ·Δw_plane·c_tex/Δv + 4/L)`, `L` the
/// plane's visible extent along track in metres (`inf` drops the extent term).
pub fn sspa_m(
    gain_px: f64,
    delta_w_plane_per_m: f64,
    extent_m: f64,
    c_tex: f64,
    delta_v_px: f64,
) -> Option<f64> {
    let extent_term = if extent_m > 0.0 { 4.0 / extent_m } else { 0.0 };
    let denom = gain_px * delta_w_plane_per_m.max(0.0) * c_tex / delta_v_px + extent_term;
    if denom.is_nan() || denom <= 0.0 {
        return None;
    }
    bounded(2.0 / denom)
}

/// Occlusion density `ρ = β·f·cos φ·D / (2·v_m)`, per metre of baseline.
#[inline]
pub fn occlusion_density_per_m(
    beta: f64,
    gain_px: f64,
    contrast_per_m: f64,
    half_extent_px: f64,
) -> f64 {
    let rho = beta * gain_px * contrast_per_m / (2.0 * half_extent_px);
    if rho.is_finite() && rho > 0.0 {
        rho
    } else {
        0.0
    }
}

/// The occlusion bound `O_max / ρ` (`None` without occlusion).
pub fn occlusion_term_m(occlusion_max: f64, density_per_m: f64) -> Option<f64> {
    if density_per_m.is_nan() || density_per_m <= 0.0 {
        return None;
    }
    bounded(occlusion_max / density_per_m)
}

/// Occlusion degree `O(b) = ρ·b`, a fraction of the field of view's rays, so
/// capped at 1.
pub fn occlusion_degree(density_per_m: f64, spacing_m: f64) -> f64 {
    let o = density_per_m * spacing_m;
    if o.is_finite() {
        o.clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// Coverage: consecutive frames overlap by at least `overlap_min` at the
/// nearest depth: `b ≤ (1 − overlap_min)·2·v_m / (f·cos φ·w_max)`.
pub fn coverage_m(
    overlap_min: f64,
    half_extent_px: f64,
    gain_px: f64,
    w_max_per_m: f64,
) -> Option<f64> {
    let denom = gain_px * w_max_per_m;
    if denom.is_nan() || denom <= 0.0 {
        return None;
    }
    bounded((1.0 - overlap_min) * 2.0 * half_extent_px / denom)
}
