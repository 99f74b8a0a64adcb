//! The single slanted plane of SSPA: a robust least-squares fit in inverse-depth
//! space, where a plane is exactly affine (`w = a·x + b·y + c` in normalised
//! image coordinates), plus its visible extent along track.

use super::depth::TrackGeometry;
use super::inverse::{InvGrid, Selector, SKY};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFit {
    /// `w = a·x + b·y + c`, `x`/`y` normalised along/across track, 1/m.
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub inliers: usize,
    /// Range of the plane's (non-negative) inverse depth over the image, 1/m.
    pub delta_w_per_m: f64,
    /// Visible extent of the inliers along track, metres.
    pub extent_m: f64,
}

/// Weighted affine fit on centred coordinates; degenerate directions (a single
/// line, a single column) are dropped rather than solved through a near-zero
/// determinant.
fn solve(pts: &[(f64, f64, f64)], keep: &[bool]) -> Option<(f64, f64, f64)> {
    let (mut n, mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0, 0.0);
    for (p, _) in pts.iter().zip(keep).filter(|(_, &k)| k) {
        n += 1.0;
        sx += p.0;
        sy += p.1;
        sw += p.2;
    }
    if n < 1.0 {
        return None;
    }
    let (mx, my, mw) = (sx / n, sy / n, sw / n);
    let (mut sxx, mut syy, mut sxy, mut sxw, mut syw) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (p, _) in pts.iter().zip(keep).filter(|(_, &k)| k) {
        let (x, y, w) = (p.0 - mx, p.1 - my, p.2 - mw);
        sxx += x * x;
        syy += y * y;
        sxy += x * y;
        sxw += x * w;
        syw += y * w;
    }
    let det = sxx * syy - sxy * sxy;
    let (a, b) = if sxx > 0.0 && syy > 0.0 && det > 1e-9 * sxx * syy {
        ((sxw * syy - syw * sxy) / det, (syw * sxx - sxw * sxy) / det)
    } else if sxx >= syy && sxx > 0.0 {
        (sxw / sxx, 0.0)
    } else if syy > 0.0 {
        (0.0, syw / syy)
    } else {
        (0.0, 0.0)
    };
    let c = mw - a * mx - b * my;
    (a.is_finite() && b.is_finite() && c.is_finite()).then_some((a, b, c))
}

/// Robust plane through the non-sky samples: least squares, then refits on the
/// samples within `trim_sigma` robust standard deviations (MAD) of the plane.
pub fn fit(
    grid: &InvGrid,
    geom: &TrackGeometry,
    pitch_rad: f64,
    iterations: usize,
    trim_sigma: f64,
    selector: &mut Selector,
) -> Option<PlaneFit> {
    let f = geom.focal_px;
    let mut pts = Vec::with_capacity(grid.valid);
    for (a, &ai) in grid.across_idx.iter().enumerate() {
        let y = geom.across_px(ai) / f;
        for (j, &w) in grid.line(a).iter().enumerate() {
            if w > SKY {
                pts.push((geom.v_px(grid.along_idx[j]) / f, y, w as f64));
            }
        }
    }
    if pts.len() < 3 {
        return None;
    }
    let mut keep = vec![true; pts.len()];
    let mut coef = solve(&pts, &keep)?;
    let mut resid = vec![0f32; pts.len()];
    for _ in 0..iterations {
        for (r, p) in resid.iter_mut().zip(&pts) {
            *r = (p.2 - (coef.0 * p.0 + coef.1 * p.1 + coef.2)).abs() as f32;
        }
        let n = resid.len() as u64;
        let [med, _] = selector.select2(&resid, true, [n / 2, n / 2])?;
        let sigma = 1.4826 * med as f64;
        // A perfect plane has sigma 0; keep a floor relative to the data so
        // rounding noise does not discard inliers.
        let limit = (trim_sigma * sigma).max(1e-7 * coef.2.abs().max(1e-12));
        let mut changed = false;
        for (k, &r) in keep.iter_mut().zip(&resid) {
            let nk = (r as f64) <= limit;
            changed |= nk != *k;
            *k = nk;
        }
        if keep.iter().filter(|&&k| k).count() < 3 {
            return None;
        }
        coef = solve(&pts, &keep)?;
        if !changed {
            break;
        }
    }
    let (a, b, c) = coef;
    let x0 = -geom.c_along_px / f;
    let x1 = (geom.along_px as f64 - geom.c_along_px) / f;
    let y0 = -geom.c_across_px / f;
    let y1 = (geom.across_px as f64 - geom.c_across_px) / f;
    let corners =
        [(x0, y0), (x0, y1), (x1, y0), (x1, y1)].map(|(x, y)| (a * x + b * y + c).max(0.0));
    let wmax = corners.iter().cloned().fold(0.0, f64::max);
    let wmin = corners.iter().cloned().fold(f64::INFINITY, f64::min);
    let (sp, cp) = pitch_rad.sin_cos();
    let (mut xmin, mut xmax, mut inliers) = (f64::INFINITY, f64::NEG_INFINITY, 0usize);
    for (p, _) in pts.iter().zip(&keep).filter(|(_, &k)| k) {
        // Along-track offset from the camera of the point at depth 1/w on ray x.
        let xr = (sp + p.0 * cp) / p.2;
        xmin = xmin.min(xr);
        xmax = xmax.max(xr);
        inliers += 1;
    }
    let extent_m = xmax - xmin;
    if !(extent_m.is_finite() && extent_m > 0.0) {
        return None;
    }
    Some(PlaneFit {
        a,
        b,
        c,
        inliers,
        delta_w_per_m: (wmax - wmin).max(0.0),
        extent_m,
    })
}
