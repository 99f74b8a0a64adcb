//! The occlusion score (paper eq. 15): the occlusion degree re-evaluated for
//! candidate pitches by re-projecting this frame's depth samples into a camera
//! rotated about the cross-track axis at the same position. A pure rotation
//! changes no visibility, only each sample's depth along the new axis, its
//! image position, and whether it stays in the field of view.

use super::depth::TrackGeometry;
use super::inverse::InvGrid;
use super::occlusion::{scan_line, BoundaryParams, BoundaryStats};
use super::spacing::{disparity_gain_px, occlusion_degree, occlusion_density_per_m};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PitchScore {
    pub pitch_rad: f64,
    /// Occlusion degree at the evaluated baseline.
    pub degree: f64,
    /// Fraction of the candidate's along-track field of view this frame covers.
    pub coverage: f64,
}

/// Candidates whose view this frame covers less than `min_coverage` of are
/// skipped: their occlusion is unknown, not small.
#[allow(clippy::too_many_arguments)]
pub fn score(
    grid: &InvGrid,
    geom: &TrackGeometry,
    pitch_rad: f64,
    candidates_rad: &[f64],
    baseline_m: f64,
    beta: f64,
    params: &BoundaryParams,
    min_coverage: f64,
) -> Vec<PitchScore> {
    let f = geom.focal_px;
    let (sp, cp) = pitch_rad.sin_cos();
    let rays: Vec<(f64, f64)> = grid
        .along_idx
        .iter()
        .map(|&i| {
            let x = geom.v_px(i) / f;
            (sp + x * cp, -cp + x * sp)
        })
        .collect();
    let mut out = Vec::with_capacity(candidates_rad.len());
    let mut scale = vec![0.0; rays.len()];
    let mut keep = vec![false; rays.len()];
    for &cand in candidates_rad {
        let (sq, cq) = cand.sin_cos();
        let (mut vmin, mut vmax) = (f64::INFINITY, f64::NEG_INFINITY);
        for (j, &(ux, uz)) in rays.iter().enumerate() {
            let depth_factor = sq * ux - cq * uz;
            keep[j] = false;
            if depth_factor > 1e-9 {
                let v = f * (cq * ux + sq * uz) / depth_factor;
                let pix = v + geom.c_along_px;
                if pix >= 0.0 && pix <= geom.along_px as f64 {
                    keep[j] = true;
                    scale[j] = 1.0 / depth_factor;
                    vmin = vmin.min(pix);
                    vmax = vmax.max(pix);
                }
            }
        }
        let coverage = if vmax >= vmin {
            ((vmax - vmin + grid.step as f64) / geom.along_px as f64).min(1.0)
        } else {
            0.0
        };
        if coverage < min_coverage {
            continue;
        }
        let mut stats = BoundaryStats::default();
        for a in 0..grid.lines {
            scan_line(
                grid.line(a),
                grid.step,
                params,
                Some(&scale),
                Some(&keep),
                None,
                &mut stats,
            );
        }
        // The part of the candidate's view this frame does not see is unknown,
        // not free of occlusion: extrapolate what is seen to the whole view.
        let rho = occlusion_density_per_m(
            beta,
            disparity_gain_px(f, cand),
            stats.mean_contrast_per_m() / coverage,
            geom.half_extent_px,
        );
        out.push(PitchScore {
            pitch_rad: cand,
            degree: occlusion_degree(rho, baseline_m),
            coverage,
        });
    }
    out
}

/// The candidate with the least occlusion; ties go to the one nearest the
/// current pitch, so a flat score never moves a gimbal.
pub fn best(scores: &[PitchScore], pitch_rad: f64) -> Option<PitchScore> {
    scores.iter().copied().min_by(|x, y| {
        let tol = 1e-12 * x.degree.max(y.degree);
        if (x.degree - y.degree).abs() <= tol {
            (x.pitch_rad - pitch_rad)
                .abs()
                .total_cmp(&(y.pitch_rad - pitch_rad).abs())
        } else {
            x.degree.total_cmp(&y.degree)
        }
    })
}
