//! The closed forms checked against a second evaluation of the same quantity:
//! disparity rates measured by differentiating the paper's projection (eq. 5)
//! with dual numbers (exact derivatives, no finite-difference error), to 1e-9.

use alfd::core::{DepthData, DepthImage, Estimator, EstimatorParams, Intrinsics, Model};
use std::ops::{Add, Div, Mul, Sub};

#[derive(Clone, Copy, Debug)]
struct Dual(f64, f64);
impl Add for Dual {
    type Output = Dual;
    fn add(self, o: Dual) -> Dual {
        Dual(self.0 + o.0, self.1 + o.1)
    }
}
impl Sub for Dual {
    type Output = Dual;
    fn sub(self, o: Dual) -> Dual {
        Dual(self.0 - o.0, self.1 - o.1)
    }
}
impl Mul for Dual {
    type Output = Dual;
    fn mul(self, o: Dual) -> Dual {
        Dual(self.0 * o.0, self.0 * o.1 + self.1 * o.0)
    }
}
impl Div for Dual {
    type Output = Dual;
    fn div(self, o: Dual) -> Dual {
        Dual(self.0 / o.0, (self.1 * o.0 - self.0 * o.1) / (o.0 * o.0))
    }
}
fn c(x: f64) -> Dual {
    Dual(x, 0.0)
}

/// Eq. 5 with the camera at `x_c = b` (the dual variable), height `z_c`.
fn project(f: f64, phi: f64, xc: Dual, zc: f64, xp: f64, zp: f64) -> Dual {
    let (s, co) = phi.sin_cos();
    let dx = c(xp) - xc;
    let dz = c(zc - zp);
    c(f) * (c(co) * dx - c(s) * dz) / (c(s) * dx + c(co) * dz)
}

/// |dv/db| at b = 0 for the point seen at image coordinate `v` with depth `d`.
fn rate(f: f64, phi: f64, v: f64, d: f64) -> f64 {
    let (s, co) = phi.sin_cos();
    let zc = 100.0;
    // The point on the ray of pixel v at depth d (inverse of eq. 5).
    let xp = d * s + v * d / f * co;
    let zp = zc - (d * co - v * d / f * s);
    let p = project(f, phi, Dual(0.0, 1.0), zc, xp, zp);
    assert!(
        (p.0 - v).abs() <= 1e-9 * (1.0 + v.abs()),
        "round trip: {} vs {v}",
        p.0
    );
    p.1.abs()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

/// Rows of two levels: `d1` on the left `split` pixels, `d2` on the right.
fn two_level(w: usize, h: usize, split: usize, d1: f32, d2: f32) -> DepthImage {
    let row: Vec<f32> = (0..w).map(|i| if i < split { d1 } else { d2 }).collect();
    DepthImage::new(w, h, DepthData::Metres(row.repeat(h))).unwrap()
}

fn params() -> EstimatorParams {
    EstimatorParams {
        score: None,
        spacing_min_m: 1e-6,
        ..EstimatorParams::with_model(Model::Occlusion)
    }
}

#[test]
fn mmds_spacing_gives_exactly_the_tolerated_disparity_range() {
    for (fov, pitch_deg, d1, d2) in [
        (69.0, 0.0, 20.0f32, 40.0f32),
        (30.0, 25.0, 3.5, 90.0),
        (120.0, -50.0, 0.01, 0.5),
    ] {
        let intr = Intrinsics::from_hfov_deg(640, 4, fov, None).unwrap();
        let phi = f64::to_radians(pitch_deg);
        let e = Estimator::new(params())
            .estimate_at(&two_level(640, 4, 200, d1, d2), &intr, phi, 1)
            .unwrap();
        let i = e.inv_depth.unwrap();
        let f = intr.focal_px();
        // Disparity rates of the nearest and farthest depth on the optical axis.
        let range =
            (rate(f, phi, 0.0, 1.0 / i.max_per_m) - rate(f, phi, 0.0, 1.0 / i.min_per_m)).abs();
        let b = e.spacing.mmds_m.unwrap();
        assert!(
            rel(b * range, 2.0) < 1e-9,
            "fov {fov} pitch {pitch_deg}: {}",
            b * range
        );
        // Coverage: the image moves by (1 − overlap)·W at the nearest depth.
        let cov = e.spacing.coverage_m.unwrap();
        let shift = cov * rate(f, phi, 0.0, 1.0 / i.max_per_m);
        assert!(rel(shift, 0.4 * 640.0) < 1e-9, "{shift}");
    }
}

#[test]
fn occlusion_density_is_the_swept_pixels_per_metre_over_the_field_of_view() {
    // Nadir: the disparity rate is f·w at every pixel (no v·sin φ term), so the
    // swept gap at each boundary is exact at its own pixel position.
    let (w, h, split) = (640usize, 6usize, 250usize);
    let (d1, d2) = (23.0f32, 61.0f32);
    let intr = Intrinsics::from_hfov_deg(w, h, 75.0, None).unwrap();
    let e = Estimator::new(params())
        .estimate_at(&two_level(w, h, split, d1, d2), &intr, 0.0, 1)
        .unwrap();
    let f = intr.focal_px();
    // The core stores inverse depth in f32: use the same values.
    let (w1, w2) = ((1.0f32 / d1) as f64, (1.0f32 / d2) as f64);
    let v_edge = (split - 1) as f64 + 0.5 - w as f64 / 2.0;
    let v_back = split as f64 + 0.5 - w as f64 / 2.0;
    let swept = (rate(f, 0.0, v_edge, 1.0 / w1) - rate(f, 0.0, v_back, 1.0 / w2)).abs();
    let rho = swept / (w as f64); // one boundary per line, 2·v_m = W
    let o = e.occlusion.unwrap();
    assert_eq!(o.boundaries, h as u64);
    assert!(
        rel(o.density_per_m, rho) < 1e-9,
        "{} vs {rho}",
        o.density_per_m
    );
    // And the occlusion-aware spacing is the baseline that sweeps O_max of the rays
    // (or MMDS, whichever is smaller).
    let want = e.spacing.mmds_m.unwrap().min(0.01 / rho);
    assert!(rel(e.spacing.occlusion_m.unwrap(), want) < 1e-9);
}

#[test]
fn pitched_occlusion_density_uses_the_on_axis_disparity_rate() {
    // DESIGN linearises with b⊥ = b·cos φ (the rate on the optical axis).
    let (w, h) = (320usize, 3usize);
    let phi = 35f64.to_radians();
    let intr = Intrinsics::from_hfov_deg(w, h, 50.0, None).unwrap();
    let e = Estimator::new(params())
        .estimate_at(&two_level(w, h, 100, 12.0, 30.0), &intr, phi, 1)
        .unwrap();
    let f = intr.focal_px();
    let (w1, w2) = ((1.0f32 / 12.0) as f64, (1.0f32 / 30.0) as f64);
    let swept = (rate(f, phi, 0.0, 1.0 / w1) - rate(f, phi, 0.0, 1.0 / w2)).abs();
    let rho = swept / w as f64;
    assert!(rel(e.occlusion.unwrap().density_per_m, rho) < 1e-9);
}
