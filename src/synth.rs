//! Analytic depth of a box world (a ground plane and axis-aligned boxes) seen by
//! a pinhole camera: depth maps whose every pixel is known in closed form, for
//! the shipped test maps, the benchmarks and the error-against-run-time table.
//!
//! World axes: `x` along track (forward), `y` left, `z` up, metres. The camera's
//! along-track image axis is image rows (`TrackAxis::Rows`): column index grows
//! forward at nadir. Depth is along the optical axis, as a RealSense reports it.

use crate::core::Intrinsics;

/// An axis-aligned box, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    /// A building: footprint `[x0, x1] × [y0, y1]` on the ground, `height_m` tall.
    pub fn building(x0: f64, x1: f64, y0: f64, y1: f64, height_m: f64) -> Aabb {
        Aabb {
            min: [x0, y0, 0.0],
            max: [x1, y1, height_m],
        }
    }

    /// Ray parameter of the first hit at `t > 0`, slab method.
    fn hit(&self, o: [f64; 3], d: [f64; 3]) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if d[k].abs() < 1e-300 {
                if o[k] < self.min[k] || o[k] > self.max[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((self.min[k] - o[k]) / d[k], (self.max[k] - o[k]) / d[k]);
            let (a, b) = if a < b { (a, b) } else { (b, a) };
            t0 = t0.max(a);
            t1 = t1.min(b);
            if t0 > t1 {
                return None;
            }
        }
        (t0 > 0.0).then_some(t0)
    }
}

/// Ground at `z = ground_z_m` (or none: all sky below too) plus boxes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BoxWorld {
    pub ground_z_m: Option<f64>,
    pub boxes: Vec<Aabb>,
}

/// Camera position (metres) and pitch (0 = nadir, positive = forward).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    pub position_m: [f64; 3],
    pub pitch_rad: f64,
}

impl BoxWorld {
    /// Depth along the optical axis of the first hit of the ray through
    /// normalised image point (`x` along track, `y` across), or `+inf`.
    pub fn depth_along_ray(&self, pose: &CameraPose, x: f64, y: f64) -> f64 {
        let (s, c) = pose.pitch_rad.sin_cos();
        // Optical axis (s, 0, -c), along-track image axis (c, 0, s), across (0, -1, 0):
        // with `d·axis = 1` the ray parameter is the depth itself.
        let d = [s + x * c, -y, -c + x * s];
        let o = pose.position_m;
        let mut t = f64::INFINITY;
        if let Some(gz) = self.ground_z_m {
            if d[2] < 0.0 && o[2] > gz {
                t = (gz - o[2]) / d[2];
            }
        }
        for b in &self.boxes {
            if let Some(tb) = b.hit(o, d) {
                t = t.min(tb);
            }
        }
        t
    }

    /// A depth map in metres (`+inf` for sky), row-major.
    pub fn render_depth(&self, pose: &CameraPose, intr: &Intrinsics) -> Vec<f32> {
        let (cx, cy) = intr.principal_px();
        let f = intr.focal_px();
        let mut out = Vec::with_capacity(intr.width() * intr.height());
        for r in 0..intr.height() {
            let y = (r as f64 + 0.5 - cy) / f;
            for i in 0..intr.width() {
                let x = (i as f64 + 0.5 - cx) / f;
                out.push(self.depth_along_ray(pose, x, y) as f32);
            }
        }
        out
    }
}

/// Metres to Z16 units of `scale_m` (0 for sky and beyond the range, as a
/// RealSense reports no return).
pub fn to_z16(depth_m: &[f32], scale_m: f64) -> Vec<u16> {
    to_z16_within(depth_m, scale_m, f64::INFINITY)
}

/// [`to_z16`], with 0 (no return) beyond `max_range_m` too: `round(d / scale)`
/// where it lies in 1..=65534, else 0. Written to vectorise: every pixel
/// computes its value and keeps it or 0, and the rounding is a truncating cast
/// (exact where the value is kept: `q − trunc(q)` is exact below 2⁵²) instead
/// of libm's `round`, a call per pixel on baseline x86-64. Same bits as
/// `round` (tested).
pub fn to_z16_within(depth_m: &[f32], scale_m: f64, max_range_m: f64) -> Vec<u16> {
    depth_m
        .iter()
        .map(|&d| {
            let q = d as f64 / scale_m;
            let keep =
                d.is_finite() && d as f64 <= max_range_m && q >= 0.5 && q < u16::MAX as f64 - 0.5;
            // Saturates (and wraps below) where `keep` is false.
            let t = q as i32;
            let r = t.wrapping_add((q - t as f64 >= 0.5) as i32);
            if keep {
                r as u16
            } else {
                0
            }
        })
        .collect()
}

/// Deterministic dropout: masks about `fraction` of the pixels (NaN), as a
/// depth sensor drops textureless or shadowed pixels.
pub fn dropout(depth_m: &mut [f32], fraction: f64, seed: u64) {
    let mut s = seed ^ 0x9E37_79B9_7F4A_7C15;
    for d in depth_m.iter_mut() {
        // splitmix64
        s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        if ((z >> 11) as f64 / (1u64 << 53) as f64) < fraction {
            *d = f32::NAN;
        }
    }
}

/// The scenes of the test data, benches and the trade-off table: a name, a
/// world and a pose. Heights and positions are the ones documented in
/// `tests/data/README.md`.
pub fn reference_scenes() -> Vec<(&'static str, BoxWorld, CameraPose)> {
    let nadir = |z: f64| CameraPose {
        position_m: [0.0, 0.0, z],
        pitch_rad: 0.0,
    };
    vec![
        (
            "roof",
            BoxWorld {
                ground_z_m: Some(0.0),
                boxes: vec![Aabb::building(-8.0, 8.0, -6.0, 6.0, 20.0)],
            },
            nadir(40.0),
        ),
        (
            "buildings",
            BoxWorld {
                ground_z_m: Some(0.0),
                boxes: vec![
                    Aabb::building(-20.0, -8.0, -15.0, 5.0, 12.0),
                    Aabb::building(2.0, 10.0, -4.0, 12.0, 25.0),
                    Aabb::building(14.0, 30.0, -20.0, -6.0, 8.0),
                    Aabb::building(18.0, 24.0, 4.0, 10.0, 30.0),
                ],
            },
            CameraPose {
                position_m: [-5.0, 0.0, 45.0],
                pitch_rad: 20f64.to_radians(),
            },
        ),
        (
            "edifice",
            BoxWorld {
                ground_z_m: Some(0.0),
                boxes: vec![
                    Aabb::building(10.0, 30.0, -10.0, 10.0, 60.0),
                    Aabb::building(-10.0, 0.0, 8.0, 20.0, 6.0),
                ],
            },
            CameraPose {
                position_m: [-20.0, 0.0, 50.0],
                pitch_rad: 35f64.to_radians(),
            },
        ),
        (
            "street",
            BoxWorld {
                ground_z_m: Some(0.0),
                boxes: vec![
                    Aabb::building(10.0, 40.0, 6.0, 20.0, 15.0),
                    Aabb::building(10.0, 40.0, -20.0, -6.0, 22.0),
                    Aabb::building(60.0, 80.0, -10.0, 10.0, 30.0),
                ],
            },
            CameraPose {
                position_m: [0.0, 0.0, 20.0],
                pitch_rad: 60f64.to_radians(),
            },
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Z16 conversion as it was written, with libm's `round`.
    fn to_z16_by_round(depth_m: &[f32], scale_m: f64) -> Vec<u16> {
        depth_m
            .iter()
            .map(|&d| {
                let z = (d as f64 / scale_m).round();
                if d.is_finite() && z >= 1.0 && z < u16::MAX as f64 {
                    z as u16
                } else {
                    0
                }
            })
            .collect()
    }

    #[test]
    fn z16_without_round_has_the_bits_of_round() {
        // Ties, their neighbours, both ends of the range, non-finite and
        // negative depths, at three scales.
        let mut d: Vec<f32> = vec![f32::NAN, f32::INFINITY, -f32::INFINITY, -1.0, -0.0, 0.0];
        for k in 0..70_000u32 {
            let tie = k as f32 + 0.5;
            d.extend([
                tie,
                f32::from_bits(tie.to_bits() - 1),
                f32::from_bits(tie.to_bits() + 1),
                k as f32,
            ]);
        }
        d.extend((0..200_000u32).map(|i| f32::from_bits(i.wrapping_mul(0x9E37_79B9) >> 1)));
        for scale_m in [1.0, 0.001, 0.01] {
            let scaled: Vec<f32> = d.iter().map(|&v| (v as f64 * scale_m) as f32).collect();
            for depth in [&d, &scaled] {
                assert_eq!(to_z16(depth, scale_m), to_z16_by_round(depth, scale_m));
            }
        }
    }

    #[test]
    fn nadir_ground_depth_is_altitude_at_centre_and_grows_off_axis() {
        let w = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![],
        };
        let pose = CameraPose {
            position_m: [0.0, 0.0, 40.0],
            pitch_rad: 0.0,
        };
        // Depth along the optical axis of a flat ground under a nadir camera is
        // the altitude at every pixel (z-depth, not range).
        assert_eq!(w.depth_along_ray(&pose, 0.0, 0.0), 40.0);
        assert!((w.depth_along_ray(&pose, 0.5, -0.3) - 40.0).abs() < 1e-12);
    }

    #[test]
    fn roof_hit_matches_hand_computation() {
        let w = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![Aabb::building(-5.0, 5.0, -5.0, 5.0, 20.0)],
        };
        let pose = CameraPose {
            position_m: [0.0, 0.0, 40.0],
            pitch_rad: 0.0,
        };
        // Roof at 20 m: depth 40 - 20 = 20 m on axis; the ray x = 0.2 reaches
        // x = 0.2·20 = 4 m at the roof, inside the 5 m half-width.
        assert!((w.depth_along_ray(&pose, 0.2, 0.0) - 20.0).abs() < 1e-12);
        // x = 0.3 meets the roof plane at x = 6 m (outside); it passes the wall
        // x = 5 at depth 5/0.3 = 16.67 m, above the roof, so it misses the box
        // and lands on the ground at depth 40.
        assert!((w.depth_along_ray(&pose, 0.3, 0.0) - 40.0).abs() < 1e-12);
    }

    #[test]
    fn pitched_camera_sees_a_wall_and_sky_beyond_the_horizon() {
        let w = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![Aabb::building(30.0, 40.0, -50.0, 50.0, 100.0)],
        };
        let pose = CameraPose {
            position_m: [0.0, 0.0, 10.0],
            pitch_rad: 90f64.to_radians(),
        };
        // Looking horizontally forward: the wall at x = 30 is 30 m away on axis.
        assert!((w.depth_along_ray(&pose, 0.0, 0.0) - 30.0).abs() < 1e-9);
        let open = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![],
        };
        // A ray tilted upwards (x > 0 points up when pitched 90°) never lands.
        assert!(open.depth_along_ray(&pose, 0.1, 0.0).is_infinite());
    }

    #[test]
    fn z16_conversion_marks_sky_and_overflow_as_no_return() {
        let z = to_z16(&[1.0, f32::INFINITY, 100.0, 0.0004, f32::NAN], 0.001);
        assert_eq!(z, vec![1000, 0, 0, 0, 0]);
    }

    #[test]
    fn dropout_is_deterministic_and_near_its_fraction() {
        let mut a = vec![1.0f32; 10_000];
        let mut b = a.clone();
        dropout(&mut a, 0.1, 7);
        dropout(&mut b, 0.1, 7);
        let na = a.iter().filter(|d| d.is_nan()).count();
        assert_eq!(na, b.iter().filter(|d| d.is_nan()).count());
        // Binomial(10000, 0.1): sd = 30, so ±150 is five sigma.
        assert!((850..=1150).contains(&na), "{na}");
    }
}
