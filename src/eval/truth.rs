//! The truth a spacing is judged by (DESIGN §3): for an in-between view and its
//! two neighbouring captures, which of the view's surface pixels each capture
//! sees, the true parallax span between the captures, and for a surface point
//! the interval of camera positions along the line from which it is visible
//! (so the captures that see it can be counted for any capture plan).
//!
//! Visibility is read from the true depth maps where they are unambiguous (the
//! four capture pixels around the reprojected point all agree with its depth)
//! and settled by an exact segment-against-scene test everywhere else, so the classification does not
//! depend on the pixel grid at occlusion edges (`tests/eval_truth.rs` checks it
//! against a closed form and against the exact test on every pixel).

use super::recon::{Geometry, View, IN_FRONT_M, SKY_M};
use crate::render::{ray_box, ray_ellipsoid};
use crate::scene::Scene;

/// A surface point's visibility: its runs `(from, to)` of camera positions
/// along the line, sorted and disjoint.
pub type Runs = Vec<(f64, f64)>;

/// The quality targets a spacing must meet (DESIGN §1, the `lightfield`
/// profile's defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Targets {
    /// Disparity range per capture step, pixels (Chai's bound with Δv = 1).
    pub parallax_px: f64,
    /// Fraction of an in-between view's surface pixels neither neighbour sees.
    pub unseen_fraction_max: f64,
    /// Captures that must see every visible surface point.
    pub views_per_point_min: u32,
}

pub const DEFAULT_TARGETS: Targets = Targets {
    parallax_px: 2.0,
    unseen_fraction_max: 0.002,
    views_per_point_min: 2,
};

/// How far beyond a segment's bounds [`Truth::occluded`] still tries a
/// primitive's exact test, metres (plus 1e-6 of the segment's length).
const SEGMENT_BOUNDS_MARGIN_M: f64 = 1e-3;

/// Pixel classes of an in-between view (indices into [`Classification::counts`]).
pub const BOTH: u8 = 0;
pub const ONE: u8 = 1;
pub const NEITHER: u8 = 2;
/// A surface pixel outside both captures' frusta.
pub const OUT_OF_BOTH: u8 = 3;
/// No surface (sky): not part of any fraction.
pub const SKY: u8 = 4;
pub const CLASS_NAMES: [&str; 3] = ["both", "one", "neither"];

/// Robust range of the disparities and depth agreement of a reprojected
/// point: the closed loop's (`core::closedloop`), so truth and prediction
/// measure the same quantity.
pub use crate::core::closedloop::PARALLAX_PERCENTILES;
use crate::core::closedloop::{self, seen_tolerance_m as tolerance_m, span_of};

/// Which captures see each pixel of an in-between view, and the parallax
/// between the captures.
#[derive(Debug, Clone)]
pub struct Classification {
    /// Per pixel, one of [`BOTH`], [`ONE`], [`NEITHER`], [`OUT_OF_BOTH`], [`SKY`].
    pub class: Vec<u8>,
    pub counts: [usize; 5],
    /// Disparity range between the two captures over the pixels both see,
    /// robust ([`PARALLAX_PERCENTILES`]), pixels; `None` if none is seen by both.
    pub parallax_span_px: Option<f64>,
    /// Pixel tests the depth maps could not decide, settled exactly.
    pub exact_tests: usize,
}

impl Classification {
    /// Surface pixels inside at least one capture's frustum.
    pub fn in_frustum(&self) -> usize {
        self.counts[BOTH as usize] + self.counts[ONE as usize] + self.counts[NEITHER as usize]
    }

    /// Fraction of the in-frustum surface pixels that neither capture sees.
    pub fn unseen_fraction(&self) -> f64 {
        let n = self.in_frustum();
        if n == 0 {
            0.0
        } else {
            self.counts[NEITHER as usize] as f64 / n as f64
        }
    }

    /// Fraction of the surface pixels outside both frusta.
    pub fn out_of_both_fraction(&self) -> f64 {
        let n = self.in_frustum() + self.counts[OUT_OF_BOTH as usize];
        if n == 0 {
            0.0
        } else {
            self.counts[OUT_OF_BOTH as usize] as f64 / n as f64
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Seen {
    Yes,
    Unsure,
}

/// What one capture shows of a view, pixel by pixel (bit `r · width + i`): whether the pixel
/// lands in the capture's frame, and whether the capture sees it there (from its depth map,
/// settled by the exact test where the map is unsure). The half of a classification that
/// depends on that capture alone: the view's other neighbour does not change it.
#[derive(Debug)]
struct Shown {
    landed: Vec<u64>,
    seen: Vec<u64>,
}

impl Shown {
    #[inline]
    fn bit(bits: &[u64], k: usize) -> bool {
        bits[k / 64] >> (k % 64) & 1 == 1
    }

    #[inline]
    fn set(bits: &mut [u64], k: usize) {
        bits[k / 64] |= 1 << (k % 64);
    }

    /// Pixels marked in a run of words.
    fn count(words: impl Iterator<Item = u64>) -> usize {
        words.map(|x| x.count_ones() as usize).sum()
    }

    fn bytes(&self) -> usize {
        (self.landed.len() + self.seen.len()) * 8
    }
}

type HalvesByPosition = std::collections::HashMap<(u64, u64), std::sync::Arc<Shown>>;

/// Halves of classifications ([`Shown`]) kept for reuse, keyed by the positions of the view
/// and the capture along the line: one view is classified against many pairs of captures
/// (each spacing of the sweeps, each plan of a search), and a capture neighbours the same
/// view in many of them (about half of `alfd eval`'s halves were made more than once). A
/// half is a function of the two positions alone, so what is kept, or was dropped at the
/// limit, changes no result. For one scene's views: a new scene needs its own.
#[derive(Debug, Default)]
pub struct Halves {
    /// Bytes kept, and the halves by (view, capture) position bits.
    kept: std::sync::Mutex<(usize, HalvesByPosition)>,
}

impl Halves {
    /// Bytes of halves kept at most; past it, new halves are used and not kept.
    pub const BYTES_MAX: usize = 1 << 30;
}

/// The scene and the survey's camera geometry: everything the truth needs.
#[derive(Debug, Clone, Copy)]
pub struct Truth<'a> {
    pub scene: &'a Scene,
    pub g: Geometry,
    /// Lateral offset and height of the survey line.
    pub y_m: f64,
    pub z_m: f64,
    /// Where the classification keeps its halves for reuse, if anywhere.
    halves: Option<&'a Halves>,
}

impl<'a> Truth<'a> {
    pub fn new(scene: &'a Scene, g: Geometry) -> Truth<'a> {
        Truth {
            scene,
            g,
            y_m: scene.survey.y_m,
            z_m: scene.survey.altitude_m,
            halves: None,
        }
    }

    /// The same truth keeping the halves of its classifications in `halves` (the views
    /// classified must be this scene's: a half is keyed by the positions alone).
    pub fn with_halves(self, halves: &'a Halves) -> Truth<'a> {
        Truth {
            halves: Some(halves),
            ..self
        }
    }

    /// `(optical axis, along-track image axis, across-track image axis)`, as
    /// the renderer's camera.
    #[inline]
    fn basis(&self) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let (s, c) = self.g.pitch_rad.sin_cos();
        ([s, 0.0, -c], [c, 0.0, s], [0.0, -1.0, 0.0])
    }

    /// The world point of pixel `(i, r)` of a view at `x_m` with depth `d`.
    #[inline]
    pub fn point(&self, x_m: f64, i: usize, r: usize, depth_m: f64) -> [f64; 3] {
        let (x, y) = self.g.norm(i, r);
        let (a, u, v) = self.basis();
        [
            x_m + depth_m * (a[0] + x * u[0] + y * v[0]),
            self.y_m + depth_m * (a[1] + x * u[1] + y * v[1]),
            self.z_m + depth_m * (a[2] + x * u[2] + y * v[2]),
        ]
    }

    /// Whether anything of the scene lies strictly between the camera at
    /// `c` and the surface point `p` (exact, the renderer's primitives).
    pub fn occluded(&self, c: [f64; 3], p: [f64; 3]) -> bool {
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        // `p` is at parameter 1. A surface through `p` itself enters at 1 up
        // to the rounding of its float32 depth (~1e-7 relative), which a
        // grazing ray (a wall seen from almost above) stretches along the
        // ray by 1/sin(angle): an occluder must lie 1 cm (plus 1e-5 of the
        // distance) before `p` to count.
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-9);
        let before = 1.0 - 1e-5 - 0.01 / len;
        // Only a primitive whose bounds meet the segment's can hold a hit at a
        // parameter in (0, 1): the bounds test is a few comparisons, the ray
        // tests divisions, and most primitives are nowhere near a given
        // segment (it was a fifth of `alfd eval`). The margin is far beyond
        // the hit's rounding (an ellipsoid's grazing root is good to ~1e-8 of
        // the distance), so no hit is lost: the classification is unchanged.
        let reach = SEGMENT_BOUNDS_MARGIN_M + 1e-6 * len;
        let lo = [0, 1, 2].map(|k| c[k].min(p[k]) - reach);
        let hi = [0, 1, 2].map(|k| c[k].max(p[k]) + reach);
        let meets =
            |min: [f64; 3], max: [f64; 3]| (0..3).all(|k| min[k] <= hi[k] && max[k] >= lo[k]);
        // The ground cannot lie between a camera above it and a point on or
        // above it.
        self.scene.boxes.iter().any(|b| {
            meets(b.min_m, b.max_m)
                && ray_box(b.min_m, b.max_m, c, d).is_some_and(|(t, _)| t < before)
        }) || self.scene.ellipsoids.iter().any(|e| {
            let (min, max) = (
                [0, 1, 2].map(|k| e.centre_m[k] - e.radii_m[k]),
                [0, 1, 2].map(|k| e.centre_m[k] + e.radii_m[k]),
            );
            meets(min, max)
                && ray_ellipsoid(e.centre_m, e.radii_m, c, d).is_some_and(|t| t < before)
        })
    }

    /// Whether the camera at `x_m` on the line sees the surface point `p`:
    /// inside its frustum and not occluded.
    pub fn visible_from(&self, p: [f64; 3], x_m: f64) -> bool {
        let c = [x_m, self.y_m, self.z_m];
        let rel = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let (a, u, v) = self.basis();
        let depth = rel[0] * a[0] + rel[1] * a[1] + rel[2] * a[2];
        if depth <= 1e-6 {
            return false;
        }
        let f = self.g.focal_px;
        let col = f * (rel[0] * u[0] + rel[1] * u[1] + rel[2] * u[2]) / depth + self.g.cx_px - 0.5;
        let row = f * (rel[0] * v[0] + rel[1] * v[1] + rel[2] * v[2]) / depth + self.g.cy_px - 0.5;
        self.g.inside(col, row) && !self.occluded(c, p)
    }

    /// [`Self::visible_from`] with the frustum bounded along track only: how
    /// long a point stays in a strip's view across track is the flight plan's
    /// side overlap, not the spacing (with a pitched camera, points near a
    /// lateral image edge leave it after a few metres of travel whatever the
    /// spacing), so views per point leave it out.
    pub fn visible_along_track(&self, p: [f64; 3], x_m: f64) -> bool {
        self.in_track_frustum(p, x_m) && !self.occluded([x_m, self.y_m, self.z_m], p)
    }

    /// Whether capture `cap` sees the point at continuous pixel `(col, row)`
    /// of its image with depth `depth_m` (from the depth map alone).
    #[inline]
    fn seen_in_map(&self, cap: &View, col: f64, row: f64, depth_m: f64) -> Seen {
        let (w, h) = (self.g.width, self.g.height);
        // `as usize` truncates and saturates below zero (and NaN) to 0: the
        // same index as `floor().max(0.0)`, without a libm call per pixel.
        let c0 = (col as usize).min(w - 1);
        let r0 = (row as usize).min(h - 1);
        let c1 = (c0 + 1).min(w - 1);
        let r1 = (r0 + 1).min(h - 1);
        let tol = tolerance_m(depth_m);
        let mut agree = 0;
        for (r, c) in [(r0, c0), (r0, c1), (r1, c0), (r1, c1)] {
            let d = cap.depth_m[r * w + c] as f64;
            let d = if d.is_finite() && d > 0.0 { d } else { SKY_M };
            if (d - depth_m).abs() <= tol {
                agree += 1;
            }
        }
        // Only "seen" is trusted from the map: a point whose four neighbours
        // all hold something nearer may still show in a sliver thinner than a
        // pixel (a wall seen almost edge-on, `--quick`'s coarse pixels), so
        // that case goes to the exact test like any disagreement.
        if agree == 4 {
            Seen::Yes
        } else {
            Seen::Unsure
        }
    }

    /// [`Self::seen_in_map`] `== Seen::Yes` of every pixel of a row (`[col, row, depth]`, a
    /// list each), four at a time: the four depths gathered, each test the same IEEE
    /// operations (the tolerance a multiply and an add, never fused). The same answer where
    /// the pixel lands in the frame (its column and row within the image): there the
    /// truncation to `i32` is `as usize`'s; elsewhere the answer is meaningless but every
    /// index is clamped into the map. Where a row's test waited on its four loads one pixel
    /// at a time, the loads now start ahead.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    fn seen_in_map_lanes_avx2(&self, cap: &View, [col, row, depth]: [&[f64]; 3], yes: &mut [bool]) {
        use std::arch::x86_64::*;
        let (w, h) = (self.g.width, self.g.height);
        let map = &cap.depth_m[..w * h];
        assert!(w * h <= i32::MAX as usize, "a map indexed by i32");
        let n = yes.len().min(col.len()).min(row.len()).min(depth.len());
        let quads = n / 4 * 4;
        let zero = _mm_setzero_si128();
        let (w_last, h_last) = (_mm_set1_epi32(w as i32 - 1), _mm_set1_epi32(h as i32 - 1));
        let (one, width) = (_mm_set1_epi32(1), _mm_set1_epi32(w as i32));
        let (sky, inf) = (_mm256_set1_pd(SKY_M), _mm256_set1_pd(f64::INFINITY));
        let abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(i64::MAX));
        // `tolerance_m`, its multiply and add.
        let (slope, offset) = (
            _mm256_set1_pd(closedloop::SEEN_TOLERANCE_SHARE),
            _mm256_set1_pd(closedloop::SEEN_TOLERANCE_M),
        );
        for q in (0..quads).step_by(4) {
            // SAFETY (the three loads): four values from `q..q + 4`, within `n`.
            let (c, r, dm) = unsafe {
                (
                    _mm256_loadu_pd(col[q..q + 4].as_ptr()),
                    _mm256_loadu_pd(row[q..q + 4].as_ptr()),
                    _mm256_loadu_pd(depth[q..q + 4].as_ptr()),
                )
            };
            let clamp = |v: __m128i, last: __m128i| _mm_min_epi32(_mm_max_epi32(v, zero), last);
            let c0 = clamp(_mm256_cvttpd_epi32(c), w_last);
            let r0 = clamp(_mm256_cvttpd_epi32(r), h_last);
            let c1 = _mm_min_epi32(_mm_add_epi32(c0, one), w_last);
            let r1 = _mm_min_epi32(_mm_add_epi32(r0, one), h_last);
            let (b0, b1) = (_mm_mullo_epi32(r0, width), _mm_mullo_epi32(r1, width));
            let tol = _mm256_add_pd(_mm256_mul_pd(slope, dm), offset);
            let mut agree = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
            for at in [(b0, c0), (b0, c1), (b1, c0), (b1, c1)] {
                let idx = _mm_add_epi32(at.0, at.1);
                // SAFETY: a clamped row times the width plus a clamped column, below `w · h`.
                let d = _mm256_cvtps_pd(unsafe { _mm_i32gather_ps::<4>(map.as_ptr(), idx) });
                let usable = _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_and_pd(d, abs_mask), inf),
                    _mm256_cmp_pd::<_CMP_GT_OQ>(d, _mm256_setzero_pd()),
                );
                let d = _mm256_blendv_pd(sky, d, usable);
                let off = _mm256_and_pd(_mm256_sub_pd(d, dm), abs_mask);
                agree = _mm256_and_pd(agree, _mm256_cmp_pd::<_CMP_LE_OQ>(off, tol));
            }
            let m = _mm256_movemask_pd(agree);
            for (l, y) in yes[q..q + 4].iter_mut().enumerate() {
                *y = m >> l & 1 == 1;
            }
        }
        let rest = col[quads..n]
            .iter()
            .zip(&row[quads..n])
            .zip(&depth[quads..n]);
        for (y, ((&c, &r), &d)) in yes[quads..n].iter_mut().zip(rest) {
            *y = self.seen_in_map(cap, c, r, d) == Seen::Yes;
        }
    }

    /// Classifies every pixel of `view` against the captures `a` and `b`.
    /// `exact_everywhere` settles every in-frustum pixel by the exact test
    /// (the reference the fast path is checked against; its halves are not kept).
    ///
    /// Compiled for AVX2 too, taken where the CPU has it (as [`Self::shown`]).
    pub fn classify(
        &self,
        view: &View,
        a: &View,
        b: &View,
        exact_everywhere: bool,
    ) -> Classification {
        self.classify_dispatched(view, a, b, exact_everywhere, true)
    }

    /// [`Self::classify`] without the class of each pixel (`class` is empty): the counts
    /// and the parallax span, what the geometry of a view needs.
    pub fn classify_counts(&self, view: &View, a: &View, b: &View) -> Classification {
        self.classify_dispatched(view, a, b, false, false)
    }

    fn classify_dispatched(
        &self,
        view: &View,
        a: &View,
        b: &View,
        exact_everywhere: bool,
        with_class: bool,
    ) -> Classification {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above, cached by std).
            return unsafe { self.classify_avx2(view, a, b, exact_everywhere, with_class) };
        }
        self.classify_portable(view, a, b, exact_everywhere, with_class)
    }

    /// [`Self::classify_portable`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn classify_avx2(
        &self,
        view: &View,
        a: &View,
        b: &View,
        exact_everywhere: bool,
        with_class: bool,
    ) -> Classification {
        self.classify_portable(view, a, b, exact_everywhere, with_class)
    }

    #[inline(always)]
    fn classify_portable(
        &self,
        view: &View,
        a: &View,
        b: &View,
        exact_everywhere: bool,
        with_class: bool,
    ) -> Classification {
        let (w, h) = (self.g.width, self.g.height);
        let [(sa, tests_a), (sb, tests_b)] =
            [a, b].map(|cap| self.shown_kept(view, cap, exact_everywhere));
        // The classes 64 pixels at a time. A half marks only surface pixels, and only those
        // in its frame as seen: both see the pixel, one does, neither does though it lands in
        // one's frame or both, or it lands in neither (the rest of the surface).
        let both: Vec<u64> = sa.seen.iter().zip(&sb.seen).map(|(x, y)| x & y).collect();
        let both_n = Shown::count(both.iter().copied());
        let one_n = Shown::count(sa.seen.iter().zip(&sb.seen).map(|(x, y)| x ^ y));
        let landed_n = Shown::count(sa.landed.iter().zip(&sb.landed).map(|(x, y)| x | y));
        let surface_n = view
            .depth_m
            .iter()
            .filter(|d| d.is_finite() && **d > 0.0)
            .count();
        let mut counts = [0usize; 5];
        counts[BOTH as usize] = both_n;
        counts[ONE as usize] = one_n;
        counts[NEITHER as usize] = landed_n - both_n - one_n;
        counts[OUT_OF_BOTH as usize] = surface_n - landed_n;
        counts[SKY as usize] = w * h - surface_n;
        let class = if with_class {
            view.depth_m
                .iter()
                .enumerate()
                .map(|(k, d)| {
                    let bit = |bits: &[u64]| Shown::bit(bits, k);
                    if !(d.is_finite() && *d > 0.0) {
                        SKY
                    } else if bit(&both) {
                        BOTH
                    } else if bit(&sa.seen) || bit(&sb.seen) {
                        ONE
                    } else if bit(&sa.landed) || bit(&sb.landed) {
                        NEITHER
                    } else {
                        OUT_OF_BOTH
                    }
                })
                .collect()
        } else {
            Vec::new()
        };
        // The disparities of the pixels both see, in pixel order: for a row that has one, each
        // pixel's squared disparity between where it lands in the two captures
        // (`Geometry::reproject` step for step; without a branch, so the divisions pack), then
        // those of the pixels both see written one after the other (every pixel written, the
        // next slot taken only after one both see: no branch; one slot to spare).
        let mut disparities = vec![0.0; both_n + 1];
        let mut taken = 0;
        let sc = self.g.pitch_rad.sin_cos();
        let (xs, ys) = self.g.norm_tables();
        let [delta_a, delta_b] = [a, b].map(|cap| view.x_m - cap.x_m);
        let mut squared = vec![0.0; w];
        for (r, &y) in ys.iter().enumerate() {
            let row = r * w..(r + 1) * w;
            if !row.clone().any(|k| Shown::bit(&both, k)) {
                continue;
            }
            let depths = &view.depth_m[row.clone()];
            for ((sq, &x), &d) in squared.iter_mut().zip(xs.iter()).zip(depths) {
                let (col_a, row_a, _) = self.g.reproject_unchecked(sc, x, y, d as f64, delta_a);
                let (col_b, row_b, _) = self.g.reproject_unchecked(sc, x, y, d as f64, delta_b);
                let (dc, dr) = (col_a - col_b, row_a - row_b);
                // Squared: the span takes the root of the two it selects.
                *sq = dc * dc + dr * dr;
            }
            for (&sq, k) in squared.iter().zip(row) {
                disparities[taken] = sq;
                taken += usize::from(Shown::bit(&both, k));
            }
        }
        disparities.truncate(taken);
        Classification {
            class,
            counts,
            // Selection, O(n): this runs for every view of every sweep.
            parallax_span_px: span_of(&mut disparities, f64::sqrt),
            exact_tests: tests_a + tests_b,
        }
    }

    /// [`Self::shown`], kept in and taken from [`Halves`] when the truth has them, and the
    /// exact tests made for it here (none for a half taken from them).
    fn shown_kept(
        &self,
        view: &View,
        cap: &View,
        exact_everywhere: bool,
    ) -> (std::sync::Arc<Shown>, usize) {
        let Some(halves) = self.halves.filter(|_| !exact_everywhere) else {
            let (s, tests) = self.shown(view, cap, exact_everywhere);
            return (std::sync::Arc::new(s), tests);
        };
        let key = (view.x_m.to_bits(), cap.x_m.to_bits());
        if let Some(s) = halves.kept.lock().expect("not poisoned").1.get(&key) {
            return (s.clone(), 0);
        }
        let (s, tests) = self.shown(view, cap, false);
        let s = std::sync::Arc::new(s);
        let mut kept = halves.kept.lock().expect("not poisoned");
        if kept.0 + s.bytes() <= Halves::BYTES_MAX {
            kept.0 += s.bytes();
            kept.1.insert(key, s.clone());
        }
        (s, tests)
    }

    /// Which of `view`'s surface pixels land in `cap`'s frame and which of those `cap` sees,
    /// and how many pixels the exact test settled.
    /// Compiled for AVX2 too, taken where the CPU has it: the same IEEE operations in the same
    /// order four lanes wide (Rust fuses no multiply-add), so the same bits.
    fn shown(&self, view: &View, cap: &View, exact_everywhere: bool) -> (Shown, usize) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above, cached by std).
            return unsafe { self.shown_avx2(view, cap, exact_everywhere) };
        }
        self.shown_portable(view, cap, exact_everywhere)
    }

    /// [`Self::shown_with`] compiled for AVX2, a row's depth-map tests four pixels at a time.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn shown_avx2(&self, view: &View, cap: &View, exact_everywhere: bool) -> (Shown, usize) {
        self.shown_with::<true>(view, cap, exact_everywhere)
    }

    fn shown_portable(&self, view: &View, cap: &View, exact_everywhere: bool) -> (Shown, usize) {
        self.shown_with::<false>(view, cap, exact_everywhere)
    }

    /// [`Self::shown`]; `AVX2` only where the CPU has it (the tests by
    /// [`Self::seen_in_map_lanes_avx2`]).
    #[inline(always)]
    fn shown_with<const AVX2: bool>(
        &self,
        view: &View,
        cap: &View,
        exact_everywhere: bool,
    ) -> (Shown, usize) {
        let (w, h) = (self.g.width, self.g.height);
        let words = (w * h).div_ceil(64);
        let (mut landed, mut seen) = (vec![0u64; words], vec![0u64; words]);
        let sc = self.g.pitch_rad.sin_cos();
        let (xs, ys) = self.g.norm_tables();
        let delta = view.x_m - cap.x_m;
        // Pixels the depth map left undecided wait for the exact test until the pass is over:
        // the call in the loop cost the common pixels their registers.
        let mut pending: Vec<(usize, usize, usize, f64)> = Vec::new();
        let (mut cols, mut rows, mut depths_at) = (vec![0.0; w], vec![0.0; w], vec![0.0; w]);
        let mut lands_in = vec![false; w];
        let mut yes = vec![false; w];
        for (r, &y) in ys.iter().enumerate() {
            let depths = &view.depth_m[r * w..(r + 1) * w];
            // Where each pixel of the row lands, first and without a branch (the divisions
            // pack; `Geometry::reproject` step for step, its `None` folded into `lands_in`),
            // then the tests in pixel order.
            for (i, (&x, &d)) in xs.iter().zip(depths).enumerate() {
                let (col, row, depth) = self.g.reproject_unchecked(sc, x, y, d as f64, delta);
                (cols[i], rows[i], depths_at[i]) = (col, row, depth);
                lands_in[i] = depth > IN_FRONT_M && self.g.inside(col, row);
            }
            #[cfg(target_arch = "x86_64")]
            if AVX2 && !exact_everywhere {
                // SAFETY: `AVX2` is true only in `shown_avx2`, taken where the CPU has it.
                unsafe { self.seen_in_map_lanes_avx2(cap, [&cols, &rows, &depths_at], &mut yes) };
            }
            for (i, &d) in depths.iter().enumerate() {
                let k = r * w + i;
                if !(d.is_finite() && d > 0.0 && lands_in[i]) {
                    continue;
                }
                Shown::set(&mut landed, k);
                let seen_here = !exact_everywhere
                    && if AVX2 {
                        yes[i]
                    } else {
                        self.seen_in_map(cap, cols[i], rows[i], depths_at[i]) == Seen::Yes
                    };
                if seen_here {
                    Shown::set(&mut seen, k);
                } else {
                    pending.push((k, i, r, d as f64));
                }
            }
        }
        let exact_tests = pending.len();
        for (k, i, r, d) in pending {
            let pt = self.point(view.x_m, i, r, d);
            if !self.occluded([cap.x_m, self.y_m, self.z_m], pt) {
                Shown::set(&mut seen, k);
            }
        }
        (Shown { landed, seen }, exact_tests)
    }

    /// Whether `p` projects inside the image along track from `x_m`.
    fn in_track_frustum(&self, p: [f64; 3], x_m: f64) -> bool {
        let rel = [p[0] - x_m, p[1] - self.y_m, p[2] - self.z_m];
        let (a, u, _) = self.basis();
        let depth = rel[0] * a[0] + rel[1] * a[1] + rel[2] * a[2];
        if depth <= 1e-6 {
            return false;
        }
        let col = self.g.focal_px * (rel[0] * u[0] + rel[1] * u[1] + rel[2] * u[2]) / depth
            + self.g.cx_px
            - 0.5;
        (-0.5..=self.g.width as f64 - 0.5).contains(&col)
    }

    /// The camera positions along the line from which `p` is visible
    /// ([`Self::visible_along_track`]), as sorted disjoint intervals: the
    /// line is walked in `step_m` from `x0` both ways until `p` leaves the
    /// frustum along track (at most `max_m`), every change between visible
    /// and hidden bisected to 1/64 of the step. An occlusion shorter than the
    /// step may be stepped over.
    pub fn visibility(&self, p: [f64; 3], x0: f64, step_m: f64, max_m: f64) -> Runs {
        let vis = |x: f64| self.visible_along_track(p, x);
        let edge = |inside: f64, outside: f64| {
            let (mut lo, mut hi) = (inside, outside);
            for _ in 0..6 {
                let mid = 0.5 * (lo + hi);
                if vis(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            (lo, hi)
        };
        // Transitions walking one way: the ends of visible runs, in order.
        let walk = |dir: f64| {
            let mut ends = Vec::new();
            let (mut last, mut last_vis) = (x0, vis(x0));
            let mut x = x0 + dir * step_m;
            while (x - x0).abs() <= max_m && self.in_track_frustum(p, x) {
                let v = vis(x);
                if v != last_vis {
                    let (a, b) = if last_vis {
                        edge(last, x)
                    } else {
                        let (a, b) = edge(x, last);
                        (b, a)
                    };
                    // The visible side of the change.
                    ends.push(if last_vis { a } else { b });
                    last_vis = v;
                }
                last = x;
                x += dir * step_m;
            }
            if last_vis {
                // Out of the frustum (bisected like a change) or at `max_m`.
                let out = (x - x0).abs() <= max_m;
                ends.push(if out { edge(last, x).0 } else { last });
            }
            ends
        };
        // Forward: x0 is visible, so ends alternate end, start, end, ...
        let fwd = walk(1.0);
        let bwd = walk(-1.0);
        let mut out = Vec::new();
        // The run through x0.
        let first_to = fwd.first().copied().unwrap_or(x0);
        let first_from = bwd.first().copied().unwrap_or(x0);
        out.push((first_from, first_to));
        for pair in fwd[1..].chunks(2) {
            if let [a, b] = pair {
                out.push((*a, *b));
            }
        }
        for pair in bwd[1..].chunks(2) {
            if let [a, b] = pair {
                out.push((*b, *a));
            }
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }

    /// The visibility intervals of the surface points of a view at `x_m`,
    /// sampled every `stride` pixels in the middle half of the image across
    /// track (`depth_m` is the view's depth map).
    pub fn view_intervals(
        &self,
        x_m: f64,
        depth_m: &[f32],
        stride: usize,
        step_m: f64,
    ) -> Vec<([f64; 3], Runs)> {
        let (w, h) = (self.g.width, self.g.height);
        let max_m = 8.0 * self.z_m.max(1.0);
        let mut out = Vec::new();
        // The middle half across track only: the fringes are the side
        // overlap's (a neighbouring strip's) to cover, and no spacing along
        // this line can help a fringe point that buildings hide from it.
        for r in (h / 4 + stride / 2..h - h / 4).step_by(stride.max(1)) {
            for i in (stride / 2..w).step_by(stride.max(1)) {
                let d = depth_m[r * w + i] as f64;
                if d.is_finite() && d > 0.0 {
                    let p = self.point(x_m, i, r, d);
                    out.push((p, self.visibility(p, x_m, step_m, max_m)));
                }
            }
        }
        out
    }
}

/// Captures (sorted positions along the line) inside any of a point's
/// visibility intervals.
pub fn captures_within(caps_m: &[f64], intervals: &[(f64, f64)]) -> usize {
    intervals
        .iter()
        .map(|&(from, to)| {
            let lo = caps_m.partition_point(|&x| x < from);
            let hi = caps_m.partition_point(|&x| x <= to);
            hi.saturating_sub(lo)
        })
        .sum()
}

/// The largest uniform spacing `s` that keeps a point in at least `k`
/// captures whatever the grid's phase, as far as its intervals of lengths
/// `L_i` guarantee: `Σ floor(L_i / s) ≥ k` (bisection; 0 if none).
pub fn point_spacing(intervals: &[(f64, f64)], k: u32) -> f64 {
    let count = |s: f64| -> u64 {
        intervals
            .iter()
            .map(|(a, b)| ((b - a) / s + 1e-9).floor().max(0.0) as u64)
            .sum()
    };
    let total: f64 = intervals.iter().map(|(a, b)| b - a).sum();
    let k = k.max(1);
    if total <= 0.0 {
        return 0.0;
    }
    // At total / k the count is at most k; far below it, at least k.
    let (mut lo, mut hi) = (total / k as f64 * 1e-6, total / k as f64 * (1.0 + 1e-9));
    if count(hi) >= k as u64 {
        return hi;
    }
    if count(lo) < k as u64 {
        return 0.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if count(mid) >= k as u64 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The largest uniform spacing that keeps every sampled point in at least
/// `k` captures ([`point_spacing`] of the worst point).
pub fn views_per_point_spacing(points: &[Runs], k: u32) -> Option<f64> {
    points
        .iter()
        .map(|iv| point_spacing(iv, k))
        .min_by(f64::total_cmp)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The depth-map test four pixels at a time answers as one pixel at a time wherever a
    /// pixel lands in the frame: a capture's map holding sky, no return, zero and negative
    /// depths (a 2×2 block of them, read as sky), depths on, inside and beyond the tolerance,
    /// points as far as sky, positions on every border and between pixels, and a count that
    /// is not a multiple of four.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_depth_map_test_in_lanes_is_the_test_one_pixel_at_a_time() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let (scene, g, views) = crate::eval::tests::views();
        let truth = Truth::new(&scene, g);
        let (w, h) = (g.width, g.height);
        let mut cap = views[4].clone();
        let odd = [f32::INFINITY, f32::NAN, 0.0, -1.0];
        for (k, v) in [(0, 0), (5, 1), (w + 3, 2), (w * h - 1, 3)] {
            cap.depth_m[k] = odd[v];
        }
        for (k, &v) in [10 * w + 20, 10 * w + 21, 11 * w + 20, 11 * w + 21]
            .into_iter()
            .zip(&odd)
        {
            cap.depth_m[k] = v;
        }
        // Positions spread evenly over the frame (the plastic number's sequence).
        let frac = |x: f64| x - x.floor();
        let (mut cols, mut rows, mut depths) = (Vec::new(), Vec::new(), Vec::new());
        let edges = [
            (-0.5, -0.5),
            (w as f64 - 0.5, h as f64 - 0.5),
            (20.5, 10.5),
            (20.0, 10.0),
        ];
        for n in 0..4001 {
            let (col, row) = match edges.get(n % 47) {
                Some(&at) => at,
                None => (
                    frac(n as f64 * 0.754_877_666_2) * w as f64 - 0.5,
                    frac(n as f64 * 0.569_840_290_9) * h as f64 - 0.5,
                ),
            };
            let m = cap.depth_m[(row as usize).min(h - 1) * w + (col as usize).min(w - 1)] as f64;
            let m = if m.is_finite() && m > 0.0 { m } else { SKY_M };
            let depth = match n % 5 {
                0 => m,
                1 => m + 0.999 * tolerance_m(m),
                2 => m - tolerance_m(m),
                3 => m * 1.05 + 0.1,
                _ => SKY_M,
            };
            cols.push(col);
            rows.push(row);
            depths.push(depth);
        }
        let mut yes = vec![false; cols.len()];
        // SAFETY: the CPU has AVX2 (checked above).
        unsafe { truth.seen_in_map_lanes_avx2(&cap, [&cols, &rows, &depths], &mut yes) };
        let (mut answers, mut seen_over_sky) = ([0usize; 2], 0);
        for (i, &got) in yes.iter().enumerate() {
            let one = truth.seen_in_map(&cap, cols[i], rows[i], depths[i]) == Seen::Yes;
            assert_eq!(
                got, one,
                "col {} row {} depth {}",
                cols[i], rows[i], depths[i]
            );
            answers[usize::from(one)] += 1;
            seen_over_sky += usize::from(one && (cols[i], rows[i]) == (20.5, 10.5));
        }
        assert!(answers[0] > 0 && answers[1] > 0, "{answers:?}");
        // Points as far as sky over the block read as sky: seen.
        assert!(seen_over_sky > 0);
    }

    /// The AVX2 build of the classification and of its halves (taken on this machine when it
    /// has AVX2) gives the portable build's bits: every half, class and parallax span of the
    /// test line's views against pairs of its captures, pixels the maps leave to the exact
    /// test among them.
    #[test]
    fn the_avx2_build_classifies_as_the_portable_one() {
        let (scene, g, views) = crate::eval::tests::views();
        let truth = Truth::new(&scene, g);
        let mut exact_tests = 0;
        let mut classes = Vec::new();
        // Views between their captures, and one beyond both (pixels out of both frames).
        for (v, a, b) in [(4, 0, 8), (2, 1, 3), (5, 2, 8), (6, 0, 7), (8, 0, 1)] {
            let (view, a, b) = (&views[v], &views[a], &views[b]);
            for cap in [a, b] {
                let (got, want) = (
                    truth.shown(view, cap, false),
                    truth.shown_portable(view, cap, false),
                );
                assert_eq!((&got.0.landed, &got.0.seen), (&want.0.landed, &want.0.seen));
                assert_eq!(got.1, want.1);
                exact_tests += got.1;
            }
            let (got, want) = (
                truth.classify(view, a, b, false),
                truth.classify_portable(view, a, b, false, true),
            );
            assert_eq!(got.class, want.class);
            assert_eq!(
                got.parallax_span_px.map(f64::to_bits),
                want.parallax_span_px.map(f64::to_bits)
            );
            // The counts are the classes counted, and the geometry alone is the same.
            let mut counted = [0usize; 5];
            for &c in &got.class {
                counted[c as usize] += 1;
            }
            assert_eq!(got.counts, counted);
            let counts = truth.classify_counts(view, a, b);
            assert!(counts.class.is_empty());
            assert_eq!(counts.counts, got.counts);
            assert_eq!(counts.parallax_span_px, got.parallax_span_px);
            classes.extend(got.class);
        }
        assert!(exact_tests > 0);
        // The classes this line has (no sky; neither is `tests/eval_truth.rs`'s street's).
        for c in [BOTH, ONE, OUT_OF_BOTH] {
            assert!(classes.contains(&c), "class {c}");
        }
    }
}
