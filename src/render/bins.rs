//! Screen-space bins of a scene's boxes and ellipsoids for one camera: the
//! image is cut into square tiles, and each tile lists, in scene order, every
//! primitive whose projection (widened by a pixel) reaches it. A camera ray
//! through a tile can hit no unlisted primitive, so the nearest hit over the
//! list is the nearest hit over the scene, ties included.

use super::Pinhole;
use crate::scene::Scene;

/// Tile side in pixels: small enough that a tile at a building's edge wastes
/// few tests, large enough that binning costs nothing beside the rays.
pub const TILE_PX: usize = 8;

/// Corners closer than this to the camera plane (metres) make the primitive
/// cover the whole image: their projection is unbounded or unreliable.
const NEAR_M: f64 = 1e-3;

/// Projection error allowance, pixels (rounding is ~1e-9 px; a pixel keeps
/// the bins conservative with room to spare).
const MARGIN_PX: f64 = 1.0;

/// Per-tile candidate lists, row-major over tiles. Entries `< boxes` are box
/// indices, the others `boxes + ellipsoid index`, ascending: the order
/// [`super::trace`] visits them in.
pub struct Bins {
    tiles_x: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Bins {
    pub fn new(scene: &Scene, cam: &Pinhole) -> Bins {
        let tiles_x = cam.width.div_ceil(TILE_PX).max(1);
        let tiles_y = cam.height.div_ceil(TILE_PX).max(1);
        let rects: Vec<Option<[usize; 4]>> = scene
            .boxes
            .iter()
            .map(|b| (b.min_m, b.max_m))
            .chain(scene.ellipsoids.iter().map(|e| {
                // The ellipsoid lies in its axis-aligned bounding box.
                let r = e.radii_m;
                let c = e.centre_m;
                (
                    [c[0] - r[0], c[1] - r[1], c[2] - r[2]],
                    [c[0] + r[0], c[1] + r[1], c[2] + r[2]],
                )
            }))
            .map(|(lo, hi)| tile_rect(cam, lo, hi, tiles_x, tiles_y))
            .collect();
        let mut count = vec![0u32; tiles_x * tiles_y + 1];
        for [x0, x1, y0, y1] in rects.iter().flatten() {
            for ty in *y0..=*y1 {
                for tx in *x0..=*x1 {
                    count[ty * tiles_x + tx + 1] += 1;
                }
            }
        }
        for k in 1..count.len() {
            count[k] += count[k - 1];
        }
        let start = count;
        let mut fill = start.clone();
        let mut items = vec![0u32; *start.last().unwrap_or(&0) as usize];
        // Primitives in scene order, so every list comes out ascending.
        for (p, rect) in rects.iter().enumerate() {
            let Some([x0, x1, y0, y1]) = rect else {
                continue;
            };
            for ty in *y0..=*y1 {
                for tx in *x0..=*x1 {
                    let slot = &mut fill[ty * tiles_x + tx];
                    items[*slot as usize] = p as u32;
                    *slot += 1;
                }
            }
        }
        Bins {
            tiles_x,
            start,
            items,
        }
    }

    /// The candidates of the tile holding pixel (`col`, `row`).
    #[inline]
    pub fn at(&self, col: usize, row: usize) -> &[u32] {
        let t = (row / TILE_PX) * self.tiles_x + col / TILE_PX;
        &self.items[self.start[t] as usize..self.start[t + 1] as usize]
    }
}

/// Inclusive tile range `[x0, x1, y0, y1]` that the projection of the box
/// `lo..hi` may reach, or `None` if it is wholly outside the image.
fn tile_rect(
    cam: &Pinhole,
    lo: [f64; 3],
    hi: [f64; 3],
    tiles_x: usize,
    tiles_y: usize,
) -> Option<[usize; 4]> {
    let whole = Some([0, tiles_x - 1, 0, tiles_y - 1]);
    let (mut c0, mut c1, mut r0, mut r1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    let mut behind = 0;
    for k in 0..8 {
        let p = [
            if k & 1 == 0 { lo[0] } else { hi[0] },
            if k & 2 == 0 { lo[1] } else { hi[1] },
            if k & 4 == 0 { lo[2] } else { hi[2] },
        ];
        let q = [p[0] - cam.o[0], p[1] - cam.o[1], p[2] - cam.o[2]];
        let z = super::dot(q, cam.a);
        // A hit has t > 0, i.e. lies in front of the camera (its depth z is
        // t): a box wholly behind cannot be hit, one reaching across the
        // camera plane (or holding the camera) may appear anywhere.
        if z < -NEAR_M {
            behind += 1;
            continue;
        }
        if z.is_nan() || z <= NEAR_M {
            return whole;
        }
        // A point at depth z seen through (col, row) has
        // q = z·(a + x·u + y·v): the inverse of the ray's construction.
        let col = cam.cx + cam.f * super::dot(q, cam.u) / z;
        let row = cam.cy + cam.f * super::dot(q, cam.v) / z;
        c0 = c0.min(col);
        c1 = c1.max(col);
        r0 = r0.min(row);
        r1 = r1.max(row);
    }
    match behind {
        0 => {}
        8 => return None,
        _ => return whole,
    }
    // In front of the camera, perspective maps the convex box onto the convex
    // hull of its corners' images.
    let (c0, c1, r0, r1) = (
        c0 - MARGIN_PX,
        c1 + MARGIN_PX,
        r0 - MARGIN_PX,
        r1 + MARGIN_PX,
    );
    let (w, h) = (cam.width as f64, cam.height as f64);
    if !(c1 >= 0.0 && r1 >= 0.0 && c0 <= w && r0 <= h) {
        return None;
    }
    let tile = |v: f64, limit: f64, tiles: usize| {
        ((v.clamp(0.0, limit) / TILE_PX as f64) as usize).min(tiles - 1)
    };
    Some([
        tile(c0, w, tiles_x),
        tile(c1, w, tiles_x),
        tile(r0, h, tiles_y),
        tile(r1, h, tiles_y),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::Intrinsics;
    use crate::render::{ray_box, ray_ellipsoid, Camera};

    fn district() -> Scene {
        Scene::parse(crate::daemon::sim::DEFAULT_SCENE, "district.toml").unwrap()
    }

    /// Every primitive a ray through a pixel meets at all (not only the
    /// nearest) is listed in that pixel's tile, at any attitude.
    #[test]
    fn no_primitive_a_ray_meets_is_left_out_of_its_tile() {
        let sc = district();
        let mut s = 11u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut met = 0;
        for _ in 0..60 {
            let cam = Camera {
                position_m: [
                    -150.0 + 200.0 * rnd(),
                    -30.0 + 60.0 * rnd(),
                    1.0 + 120.0 * rnd(),
                ],
                roll_rad: (-60.0 + 120.0 * rnd()).to_radians(),
                pitch_rad: (-80.0 + 160.0 * rnd()).to_radians(),
                yaw_rad: (-180.0 + 360.0 * rnd()).to_radians(),
                intrinsics: Intrinsics::from_hfov_deg(64, 48, 30.0 + 120.0 * rnd(), None).unwrap(),
            };
            let pin = Pinhole::new(&cam);
            let bins = Bins::new(&sc, &pin);
            for _ in 0..400 {
                let (col, row) = (64.0 * rnd(), 48.0 * rnd());
                let d = cam.ray(col, row);
                let listed = bins.at(col as usize, row as usize);
                let o = cam.position_m;
                for (p, b) in sc.boxes.iter().enumerate() {
                    if ray_box(b.min_m, b.max_m, o, d).is_some() {
                        met += 1;
                        assert!(listed.contains(&(p as u32)), "box {p} at {col},{row}");
                    }
                }
                for (j, e) in sc.ellipsoids.iter().enumerate() {
                    if ray_ellipsoid(e.centre_m, e.radii_m, o, d).is_some() {
                        met += 1;
                        let p = (sc.boxes.len() + j) as u32;
                        assert!(listed.contains(&p), "ellipsoid {j} at {col},{row}");
                    }
                }
            }
        }
        assert!(met > 1000, "the rays meet primitives: {met}");
    }

    #[test]
    fn lists_are_ascending_and_a_nadir_view_culls_most_primitives() {
        let sc = district();
        let cam = crate::render::survey_camera(&sc, 0.0, 640, 480);
        let bins = Bins::new(&sc, &Pinhole::new(&cam));
        let mut longest = 0;
        for r in (0..480).step_by(TILE_PX) {
            for c in (0..640).step_by(TILE_PX) {
                let l = bins.at(c, r);
                assert!(l.windows(2).all(|w| w[0] < w[1]));
                longest = longest.max(l.len());
            }
        }
        let total = sc.boxes.len() + sc.ellipsoids.len();
        assert!(longest < total / 2, "{longest} of {total}");
    }
}
