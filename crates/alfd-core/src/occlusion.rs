//! Occlusion boundaries along track and the occlusion density (DESIGN §1, eq. 6
//! linearised): a boundary is a pair of consecutive valid samples on a line in
//! the flight direction whose inverse depths differ by more than the noise
//! threshold; moving the camera by `b` opens `f·cos φ·b·(w_f − w_b)` pixels there.

use super::inverse::{InvGrid, SKY};

/// When two neighbouring samples are far enough apart in inverse depth to be an
/// occlusion edge rather than a slanted surface or sensor noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoundaryParams {
    /// Absolute threshold `τ_w`, 1/m.
    pub tau_abs_per_m: f64,
    /// Relative threshold on the larger inverse depth of the pair, per pixel
    /// of sampling step.
    pub tau_rel: f64,
    /// Largest run of masked pixels (original resolution) a pair may straddle:
    /// stereo sensors leave a masked shadow exactly beside occluding edges.
    pub max_gap_px: usize,
    /// Whether sky (`w = 0`) counts as a background surface.
    pub sky_is_scene: bool,
}

/// Boundaries summed over lines.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BoundaryStats {
    pub boundaries: u64,
    /// Lines with at least one tested pair.
    pub lines: u64,
    /// Sum over all boundaries of `w_f − w_b`, 1/m.
    pub contrast_sum_per_m: f64,
}

impl BoundaryStats {
    /// `D`: mean over lines of the summed contrast, 1/m (0 without lines).
    pub fn mean_contrast_per_m(&self) -> f64 {
        if self.lines == 0 {
            0.0
        } else {
            self.contrast_sum_per_m / self.lines as f64
        }
    }
}

#[inline]
fn usable(w: f32, sky_is_scene: bool) -> bool {
    w > SKY || (sky_is_scene && w == SKY)
}

/// Scan one line; `scale[j]` multiplies each sample (1 for the camera's own
/// view, the depth re-projection factor for a candidate pitch) and `keep[j]`
/// masks samples outside the candidate's field of view. `weight[j]`, if
/// given, scales the contrast of a boundary by the mean weight of its two
/// samples (the per-pixel disparity gain relative to the optical axis).
///
/// The relative threshold grows with the sampling step: it bounds the inverse
/// depth *gradient* (per pixel) that a surface may have, so a steep wall that
/// is smooth at full resolution does not become a row of false edges once the
/// map is decimated. (Compensating neighbouring slopes instead breaks the
/// monotonicity of the contrast in the jump, which the property tests hold.)
#[inline]
pub fn scan_line(
    line: &[f32],
    step: usize,
    p: &BoundaryParams,
    scale: Option<&[f64]>,
    keep: Option<&[bool]>,
    weight: Option<&[f64]>,
    stats: &mut BoundaryStats,
) {
    let step = step.max(1);
    let weigh =
        |diff: f64, ja: usize, jb: usize| weight.map_or(diff, |g| diff * 0.5 * (g[ja] + g[jb]));
    let tau_rel = p.tau_rel * step as f64;
    if scale.is_none() && keep.is_none() && line.len() >= 2 {
        // Most lines have no masked sample: compare neighbours directly.
        let all_usable = line
            .iter()
            .fold(true, |acc, &w| acc & usable(w, p.sky_is_scene));
        if all_usable {
            let mut prev = line[0] as f64;
            for (j, &w) in line.iter().enumerate().skip(1) {
                let w = w as f64;
                let diff = (w - prev).abs();
                if diff > p.tau_abs_per_m + tau_rel * w.max(prev) {
                    stats.boundaries += 1;
                    stats.contrast_sum_per_m += weigh(diff, j - 1, j);
                }
                prev = w;
            }
            stats.lines += 1;
            return;
        }
    }
    let max_gap_samples = p.max_gap_px / step;
    let mut last: Option<(usize, f64)> = None;
    let mut tested = false;
    for (j, &w) in line.iter().enumerate() {
        if !usable(w, p.sky_is_scene) || keep.is_some_and(|k| !k[j]) {
            continue;
        }
        let w = w as f64 * scale.map_or(1.0, |s| s[j]);
        if let Some((jl, wl)) = last {
            if j - jl - 1 <= max_gap_samples {
                tested = true;
                let diff = (w - wl).abs();
                if diff > p.tau_abs_per_m + tau_rel * w.max(wl) {
                    stats.boundaries += 1;
                    stats.contrast_sum_per_m += weigh(diff, jl, j);
                }
            }
        }
        last = Some((j, w));
    }
    if tested {
        stats.lines += 1;
    }
}

/// Boundaries over every line of the grid, in the camera's own view, with an
/// optional per-sample weight on the contrast.
pub fn scan(grid: &InvGrid, p: &BoundaryParams, weight: Option<&[f64]>) -> BoundaryStats {
    let mut stats = BoundaryStats::default();
    for a in 0..grid.lines {
        scan_line(grid.line(a), grid.step, p, None, None, weight, &mut stats);
    }
    stats
}
