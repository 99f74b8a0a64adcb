//! The closed loop (DESIGN §1, issue 13): instead of predicting from one frame,
//! measure against the last capture. The capture's depth (decimated) is warped
//! into each frame's full 6-DoF pose: the parallax span between the two and the
//! fraction of an in-between frame that neither the capture nor the current
//! frame sees (what the next capture would leave unseen if taken now). Pure:
//! depth, poses and distances are arguments.

use super::depth::{DepthData, DepthImage, Intrinsics};
use glam::{DMat3, DVec3};

/// Robust ends of the disparity distribution, the percentiles of the
/// estimator's inverse-depth range; the evaluation's truth uses the same.
pub const PARALLAX_PERCENTILES: (f64, f64) = (0.005, 0.995);

/// How far in front of a reprojected point a view's depth may be and still
/// show its surface: the warping renderer's rule (2 % + 5 cm), shared with
/// the evaluation's truth.
#[inline]
pub fn seen_tolerance_m(depth_m: f64) -> f64 {
    SEEN_TOLERANCE_SHARE * depth_m + SEEN_TOLERANCE_M
}

/// [`seen_tolerance_m`]'s share of the depth, and its constant part (metres): for code
/// that applies it several depths at once.
pub const SEEN_TOLERANCE_SHARE: f64 = 0.02;
pub const SEEN_TOLERANCE_M: f64 = 0.05;

/// Frames kept since the last capture; beyond it every other one is dropped
/// (the in-between frame is then the nearest kept one to the middle).
pub const KEPT_FRAMES_MAX: usize = 64;

/// A depth frame sampled every `step` pixels, in metres (`+inf` sky, NaN invalid).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthSnapshot {
    pub step: usize,
    pub cols: usize,
    pub rows: usize,
    pub focal_px: f64,
    pub principal_px: (f64, f64),
    pub width: usize,
    pub height: usize,
    /// The pixel at the top left of each block of `step × step` pixels.
    pub depth_m: Vec<f32>,
    /// The farthest valid depth in each block (NaN: none valid). What the
    /// frame shows behind its samples: a surface strip narrower than the step
    /// (a street floor between walls, a wall seen edge-on, where the depth
    /// changes by more than the seen tolerance from one pixel to the next)
    /// is in it when no sample lands on it.
    pub far_m: Vec<f32>,
}

/// Samples of a frame the closed loop keeps, about (a 640 × 480 frame every
/// 8th pixel): its cost per frame is a few of these warps.
pub const KEPT_SAMPLES: usize = 4800;

impl DepthSnapshot {
    /// The snapshot the closed loop keeps: about [`KEPT_SAMPLES`] samples.
    pub fn kept(image: &DepthImage, intr: &Intrinsics) -> DepthSnapshot {
        let step = ((image.pixel_count() as f64 / KEPT_SAMPLES as f64)
            .sqrt()
            .ceil() as usize)
            .max(1);
        DepthSnapshot::new(image, intr, step)
    }

    pub fn new(image: &DepthImage, intr: &Intrinsics, step: usize) -> DepthSnapshot {
        let step = step.max(1);
        let (w, h) = (image.width(), image.height());
        // Each pixel as a key that orders as its depth, 0 where invalid (no
        // return, saturated, or not positive), and the key's depth in metres.
        let (depth_m, far_m) = match image.data() {
            DepthData::Z16 { data, scale_m } => sample(
                data,
                (w, h, step),
                |z| if z == u16::MAX { 0 } else { z },
                |z| match z {
                    0 => f32::NAN,
                    z => (z as f64 * scale_m) as f32,
                },
            ),
            DepthData::Metres(d) => sample(
                d,
                (w, h, step),
                |z| if z > 0.0 { z } else { 0.0 },
                |z| if z > 0.0 { z } else { f32::NAN },
            ),
        };
        let (cols, rows) = (w.div_ceil(step), h.div_ceil(step));
        DepthSnapshot {
            step,
            cols,
            rows,
            focal_px: intr.focal_px(),
            principal_px: intr.principal_px(),
            width: w,
            height: h,
            depth_m,
            far_m,
        }
    }

    /// The four samples around the image point `(u, v)` (px, pixel `i`
    /// spans `[i, i + 1)`) and the farthest depth of the block holding its
    /// pixel, `None` outside the image.
    fn around(&self, u: f64, v: f64) -> Option<[f32; 5]> {
        if !(u >= 0.0 && v >= 0.0 && u < self.width as f64 && v < self.height as f64) {
            return None;
        }
        let s = self.step as f64;
        let (x, y) = (((u - 0.5) / s).max(0.0), ((v - 0.5) / s).max(0.0));
        // `x, y ≥ 0`: the cast is the floor, without the libm call baseline
        // x86-64 makes for `floor` (no SSE4.1).
        let (c0, r0) = (
            (x as usize).min(self.cols - 1),
            (y as usize).min(self.rows - 1),
        );
        let (c1, r1) = ((c0 + 1).min(self.cols - 1), (r0 + 1).min(self.rows - 1));
        let d = |c: usize, r: usize| self.depth_m[r * self.cols + c];
        // `u < width`, so the block is in range.
        let (bc, br) = (u as usize / self.step, v as usize / self.step);
        let far = self.far_m[br * self.cols + bc];
        Some([d(c0, r0), d(c1, r0), d(c0, r1), d(c1, r1), far])
    }
}

/// Every `step`-th pixel of a `w × h` frame, and the farthest valid depth of
/// each block (NaN: none valid), in one pass over the frame.
///
/// `key` orders as the depth and is `K::default()` (0) where the pixel is
/// invalid; `metres` is monotone in the key, so the farthest depth is the
/// largest key's, converted once per block (the same `f32` as converting every
/// pixel and taking the `max`). The rows of a block row are maxed into one row
/// of keys, element by element (it vectorises), then each block's `step`
/// keys: converting every pixel through `f64` was 15× a read of the frame.
fn sample<T: Copy, K: Copy + Default + PartialOrd>(
    data: &[T],
    (w, h, step): (usize, usize, usize),
    key: impl Fn(T) -> K,
    metres: impl Fn(K) -> f32,
) -> (Vec<f32>, Vec<f32>) {
    let (cols, rows) = (w.div_ceil(step), h.div_ceil(step));
    let mut depth_m = Vec::with_capacity(cols * rows);
    let mut far_m = Vec::with_capacity(cols * rows);
    let mut row_max = vec![K::default(); w];
    for r0 in (0..h).step_by(step) {
        for c in (0..w).step_by(step) {
            depth_m.push(metres(key(data[r0 * w + c])));
        }
        row_max.fill(K::default());
        for line in data[r0 * w..(r0 + step).min(h) * w].chunks_exact(w) {
            for (m, &z) in row_max.iter_mut().zip(line) {
                // Stored unconditionally: a select, not a branch per lane.
                let k = key(z);
                *m = if k > *m { k } else { *m };
            }
        }
        for block in row_max.chunks(step) {
            let far = block
                .iter()
                .fold(K::default(), |m, &k| if k > m { k } else { m });
            far_m.push(metres(far));
        }
    }
    (depth_m, far_m)
}

/// A snapshot where it was taken: OpenCV camera axes (x right, y down, z along
/// the optical axis) → NED, and the camera's NED position.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    pub depth: DepthSnapshot,
    pub cam_to_ned: DMat3,
    pub pos_ned_m: DVec3,
}

impl View {
    /// The surface point of sample `(c, r)` in NED, or `None` (sky, invalid).
    fn point(&self, c: usize, r: usize) -> Option<(DVec3, DVec3)> {
        let z = self.depth.depth_m[r * self.depth.cols + c] as f64;
        if !(z.is_finite() && z > 0.0) {
            return None;
        }
        let (cx, cy) = self.depth.principal_px;
        let f = self.depth.focal_px;
        // Pixel centres at `i + 0.5`, as the intrinsics' principal point.
        let (u, v) = (
            (c * self.depth.step) as f64 + 0.5,
            (r * self.depth.step) as f64 + 0.5,
        );
        let ray_cam = DVec3::new((u - cx) / f, (v - cy) / f, 1.0);
        let ray = self.cam_to_ned * ray_cam;
        Some((self.pos_ned_m + ray * z, ray))
    }

    /// Where a NED point lands in this view: `(u, v, depth)`, `None` behind it.
    fn project(&self, p: DVec3) -> Option<(f64, f64, f64)> {
        let q = self.cam_to_ned.transpose() * (p - self.pos_ned_m);
        if q.z <= 1e-9 {
            return None;
        }
        let (cx, cy) = self.depth.principal_px;
        let f = self.depth.focal_px;
        Some((cx + f * q.x / q.z, cy + f * q.y / q.z, q.z))
    }

    /// Whether this view sees `p`: inside the frame and not behind the surface
    /// its depth shows there (2 % + 5 cm, the truth's tolerance). No valid
    /// depth around it is `Unknown`.
    fn sees(&self, p: DVec3) -> Sight {
        self.sees_projected(self.project(p))
    }

    /// [`Self::sees`] from the point's projection into this view.
    fn sees_projected(&self, at: Option<(f64, f64, f64)>) -> Sight {
        let Some((u, v, z)) = at else {
            return Sight::Outside;
        };
        let Some(ds) = self.depth.around(u, v) else {
            return Sight::Outside;
        };
        if ds.iter().all(|d| d.is_nan()) {
            return Sight::Unknown;
        }
        // Seen if any sample around the projection, or any pixel of its block,
        // shows the point's surface: requiring more hides a strip along every
        // depth edge and on walls seen edge-on (spurious captures); the cost
        // is that disocclusions narrower than a block go unseen
        // (tests/closed_loop.rs measures both against the truth).
        if ds
            .iter()
            .any(|&d| !d.is_nan() && d as f64 >= z - seen_tolerance_m(z))
        {
            Sight::Seen
        } else {
            Sight::Hidden
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sight {
    Seen,
    Hidden,
    Outside,
    Unknown,
}

/// The capture against a later frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pair {
    /// Disparity span (robust) over the frame's samples the capture sees, with
    /// the rotation between the two taken out (disparity against the point at
    /// infinity on the same ray), px.
    pub parallax_span_px: Option<f64>,
    /// Fraction of the frame's surface samples inside the capture's frame.
    pub in_view_fraction: f64,
    /// Fraction of the frame's in-view surface samples the capture does not see.
    pub hidden_fraction: f64,
    pub samples: u64,
}

/// The capture `a` against the frame `b`.
pub fn pair(a: &View, b: &View) -> Pair {
    let mut disp = Vec::with_capacity(b.depth.depth_m.len());
    let (mut n, mut inside, mut hidden) = (0u64, 0u64, 0u64);
    for r in 0..b.depth.rows {
        for c in 0..b.depth.cols {
            let Some((p, ray)) = b.point(c, r) else {
                continue;
            };
            n += 1;
            let at = a.project(p);
            match a.sees_projected(at) {
                Sight::Outside | Sight::Unknown => {}
                Sight::Hidden => {
                    inside += 1;
                    hidden += 1;
                }
                Sight::Seen => {
                    inside += 1;
                    // Against the same ray at infinity: rotation gives no parallax.
                    if let (Some((u, v, _)), Some((ui, vi, _))) = (at, a.project(a.pos_ned_m + ray))
                    {
                        disp.push((u - ui).hypot(v - vi));
                    }
                }
            }
        }
    }
    Pair {
        parallax_span_px: span(&mut disp),
        in_view_fraction: if n > 0 { inside as f64 / n as f64 } else { 0.0 },
        hidden_fraction: if inside > 0 {
            hidden as f64 / inside as f64
        } else {
            0.0
        },
        samples: n,
    }
}

/// The robust span of `d` ([`PARALLAX_PERCENTILES`]) by selection, O(n);
/// `None` when empty. Reorders `d`.
pub fn span(d: &mut [f64]) -> Option<f64> {
    span_of(d, |x| x)
}

/// [`span`] of `f(d)` for a non-decreasing `f`, applied to the two selected
/// values only: the `k`-th smallest of `f(d)` is `f` of the `k`-th smallest of
/// `d`, so the span has the same bits as `f` applied to every value (a square
/// root per sample, when `d` holds squared distances).
pub fn span_of(d: &mut [f64], f: impl Fn(f64) -> f64) -> Option<f64> {
    if d.is_empty() {
        return None;
    }
    let n = d.len();
    let lo = ((n - 1) as f64 * PARALLAX_PERCENTILES.0).round() as usize;
    let hi = ((n - 1) as f64 * PARALLAX_PERCENTILES.1).round() as usize;
    let (q_lo, q_hi) = select_two(d, lo.min(hi), hi);
    Some(f(q_hi) - f(q_lo))
}

/// Below this many values [`select_two`] selects directly: its sample costs more than it saves.
const SELECT_SAMPLED_MIN: usize = 2048;

/// The values of ranks `lo ≤ hi` of `d` in `f64::total_cmp`'s order (0: the smallest), as
/// `select_nth_unstable_by` gives them; reorders `d`.
///
/// The percentiles of a span sit near the ends: one pass keeps the values at or beyond a
/// threshold taken from a sorted sample, about twice as many as the rank needs, and the rank
/// is selected among those few. Every value left out lies strictly inside the threshold, so
/// when the kept ones are at least as many as the rank's distance from its end, the value is
/// the same; otherwise (a sample unlike the rest) the whole slice is selected, as without
/// the sample. Equal under `total_cmp` is equal bits, so the same value is the same bits.
pub fn select_two(d: &mut [f64], lo: usize, hi: usize) -> (f64, f64) {
    use std::cmp::Ordering::{Greater, Less};
    let n = d.len();
    assert!(lo <= hi && hi < n, "ranks {lo} ≤ {hi} of {n} values");
    // From the top end `hi` is the `above`-th largest; from the bottom `lo` the `below`-th smallest.
    let (above, below) = (n - hi, lo + 1);
    if n < SELECT_SAMPLED_MIN || 8 * above.max(below) > n {
        let q_hi = *d.select_nth_unstable_by(hi, f64::total_cmp).1;
        let q_lo = *d[..=hi].select_nth_unstable_by(lo, f64::total_cmp).1;
        return (q_lo, q_hi);
    }
    // A sample of 256 to 511 values, evenly strided, sorted.
    let stride = n / 256;
    let mut sample: Vec<f64> = d.iter().step_by(stride).copied().collect();
    sample.sort_unstable_by(f64::total_cmp);
    let m = sample.len();
    // Each sampled value stands for `stride` values: aim at twice the count needed, and two
    // sampled values more.
    let reach = |count: usize| (2 * count).div_ceil(stride) + 2;
    let t_hi = sample[m - reach(above).min(m)];
    let t_lo = sample[reach(below).min(m) - 1];
    let (mut top, mut bottom) = (Vec::new(), Vec::new());
    for &x in d.iter() {
        if x.total_cmp(&t_hi) != Less {
            top.push(x);
        }
        if x.total_cmp(&t_lo) != Greater {
            bottom.push(x);
        }
    }
    if top.len() < above || bottom.len() < below {
        let q_hi = *d.select_nth_unstable_by(hi, f64::total_cmp).1;
        let q_lo = *d[..=hi].select_nth_unstable_by(lo, f64::total_cmp).1;
        return (q_lo, q_hi);
    }
    let k = top.len() - above;
    let q_hi = *top.select_nth_unstable_by(k, f64::total_cmp).1;
    let q_lo = *bottom.select_nth_unstable_by(lo, f64::total_cmp).1;
    (q_lo, q_hi)
}

/// Fraction of `mid`'s surface samples inside at least one of `a`, `b` that
/// neither sees (the truth's `NEITHER / in_frustum`). Samples an invalid depth
/// leaves undecided count as seen: missing depth must not trigger captures.
pub fn unseen_fraction(mid: &View, a: &View, b: &View) -> f64 {
    let (mut in_frustum, mut neither) = (0u64, 0u64);
    for r in 0..mid.depth.rows {
        for c in 0..mid.depth.cols {
            let Some((p, _)) = mid.point(c, r) else {
                continue;
            };
            let seen = |s| matches!(s, Sight::Seen | Sight::Unknown);
            // Seen by `a`: in a frustum and not unseen, whatever `b` shows
            // (most of the frame; `b` is not warped).
            let sa = a.sees(p);
            if seen(sa) {
                in_frustum += 1;
                continue;
            }
            let sb = b.sees(p);
            if sa == Sight::Outside && sb == Sight::Outside {
                continue;
            }
            in_frustum += 1;
            if !seen(sb) {
                neither += 1;
            }
        }
    }
    if in_frustum == 0 {
        0.0
    } else {
        neither as f64 / in_frustum as f64
    }
}

/// The targets the closed loop holds (the quality model's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosedLoopTargets {
    pub parallax_px: Option<f64>,
    pub unseen_fraction_max: f64,
}

/// One frame's measurement against the last capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measure {
    /// Distance flown since the capture, m.
    pub distance_m: f64,
    pub parallax_px: Option<f64>,
    /// Unseen fraction of the frame nearest the middle if the next capture
    /// were taken now.
    pub unseen_fraction: f64,
    pub in_view_fraction: f64,
    /// The largest spacing the measurements allow, extrapolated one frame
    /// ahead (`None`: no target is near).
    pub spacing_m: Option<f64>,
    /// Which target sets `spacing_m`: `parallax` or `unseen_fraction`.
    pub bound: Option<&'static str>,
}

/// The closed loop's state: the last capture and the frames since.
#[derive(Debug, Clone, Default)]
pub struct ClosedLoop {
    capture: Option<(View, f64)>,
    kept: Vec<(View, f64)>,
    last: Option<Measure>,
}

impl ClosedLoop {
    /// A capture was taken at `view`, at odometer reading `odometer_m`.
    pub fn on_capture(&mut self, view: View, odometer_m: f64) {
        self.capture = Some((view, odometer_m));
        self.kept.clear();
        self.last = None;
    }

    /// Measures `view` (at `odometer_m`) against the last capture; `next_step_m`
    /// is the travel to the next frame. `None` before the first capture.
    pub fn on_frame(
        &mut self,
        view: View,
        odometer_m: f64,
        next_step_m: f64,
        t: &ClosedLoopTargets,
    ) -> Option<Measure> {
        let (cap, cap_odo) = self.capture.as_ref()?;
        let d = (odometer_m - cap_odo).max(0.0);
        let p = pair(cap, &view);
        // The kept frame nearest the middle stands for the in-between view.
        let mid = self
            .kept
            .iter()
            .min_by(|x, y| {
                ((x.1 - cap_odo) - 0.5 * d)
                    .abs()
                    .total_cmp(&((y.1 - cap_odo) - 0.5 * d).abs())
            })
            .map(|(v, _)| v);
        let unseen = mid.map_or(0.0, |m| unseen_fraction(m, cap, &view));
        let step = if next_step_m.is_finite() {
            next_step_m.max(0.0)
        } else {
            0.0
        };
        let mut best: Option<(f64, &'static str)> = None;
        let mut offer = |s: f64, name: &'static str| {
            if s.is_finite() && best.is_none_or(|(b, _)| s < b) {
                best = Some((s.max(0.0), name));
            }
        };
        // Parallax grows in proportion to the baseline: where it reaches the target.
        if let (Some(target), Some(px)) = (t.parallax_px, p.parallax_span_px) {
            if px > 0.0 && d > 0.0 {
                offer(d * target / px, "parallax");
            }
        }
        // The unseen fraction is not linear (0 until the shortest interval):
        // past the target, capture now; rising, extrapolate one frame ahead.
        if unseen > t.unseen_fraction_max {
            offer(d, "unseen_fraction");
        } else if let Some(prev) = self.last {
            let dd = d - prev.distance_m;
            let rise = unseen - prev.unseen_fraction;
            if dd > 0.0 && rise > 0.0 && unseen + rise / dd * step > t.unseen_fraction_max {
                offer(d, "unseen_fraction");
            }
        }
        let m = Measure {
            distance_m: d,
            parallax_px: p.parallax_span_px,
            unseen_fraction: unseen,
            in_view_fraction: p.in_view_fraction,
            spacing_m: best.map(|b| b.0),
            bound: best.map(|b| b.1),
        };
        self.last = Some(m);
        self.kept.push((view, odometer_m));
        if self.kept.len() > KEPT_FRAMES_MAX {
            // Thin by halves, keeping the newest: bounded memory on long legs.
            let n = self.kept.len();
            let mut i = 0;
            self.kept.retain(|_| {
                i += 1;
                (n - i) % 2 == 0
            });
        }
        Some(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn metres(w: usize, h: usize, d: Vec<f32>) -> DepthImage {
        DepthImage::new(w, h, DepthData::Metres(d)).unwrap()
    }

    #[test]
    fn the_span_of_squares_rooted_is_the_span_of_roots() {
        let mut s = 3u64;
        for n in [1usize, 2, 3, 10, 201, 1000] {
            let mut sq: Vec<f64> = (0..n)
                .map(|k| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    // Pairs of whole pixel offsets (ties) and fractional ones.
                    let (dc, dr) = if k % 3 == 0 {
                        ((s >> 60) as f64, (s >> 58 & 3) as f64)
                    } else {
                        (
                            (s >> 11) as f64 / (1u64 << 49) as f64,
                            (s & 0xffff) as f64 / 977.0,
                        )
                    };
                    dc * dc + dr * dr
                })
                .collect();
            let mut roots: Vec<f64> = sq.iter().map(|x| x.sqrt()).collect();
            let want = span(&mut roots).map(f64::to_bits);
            assert_eq!(span_of(&mut sq, f64::sqrt).map(f64::to_bits), want, "{n}");
        }
        assert_eq!(span_of(&mut [], f64::sqrt), None);
    }

    /// `select_two`'s ranks as two plain selections of the whole slice.
    fn select_two_plainly(d: &[f64], lo: usize, hi: usize) -> (u64, u64) {
        let mut v = d.to_vec();
        let q_hi = *v.select_nth_unstable_by(hi, f64::total_cmp).1;
        let q_lo = *v.select_nth_unstable_by(lo, f64::total_cmp).1;
        (q_lo.to_bits(), q_hi.to_bits())
    }

    proptest! {
        #[test]
        fn select_two_is_two_plain_selections(
            // Few distinct values (ties at the threshold), any bits (NaN, ±0, ±∞), or spread.
            values in proptest::collection::vec(
                prop_oneof![
                    (0u8..6).prop_map(f64::from),
                    proptest::num::f64::ANY,
                    0.0f64..1e4,
                ],
                0..12_000,
            ),
            lo_at in 0.0f64..=1.0,
            hi_at in 0.0f64..=1.0,
        ) {
            let n = values.len();
            prop_assume!(n > 0);
            let (a, b) = (((n - 1) as f64 * lo_at) as usize, ((n - 1) as f64 * hi_at) as usize);
            for (lo, hi) in [
                (a.min(b), a.max(b)),
                // The span's own ranks.
                (
                    ((n - 1) as f64 * PARALLAX_PERCENTILES.0).round() as usize,
                    ((n - 1) as f64 * PARALLAX_PERCENTILES.1).round() as usize,
                ),
            ] {
                let mut d = values.clone();
                let (q_lo, q_hi) = select_two(&mut d, lo, hi);
                prop_assert_eq!((q_lo.to_bits(), q_hi.to_bits()), select_two_plainly(&values, lo, hi));
            }
        }
    }

    #[test]
    fn select_two_with_a_sample_unlike_the_rest_still_selects_the_ranks() {
        // The sampled positions (every `n / 256`-th) hold the largest and the smallest values,
        // so each threshold keeps too few values and the whole slice is selected.
        let n = 30_000;
        let stride = n / 256;
        let d: Vec<f64> = (0..n)
            .map(|k| match (k % stride == 0, k % (2 * stride) == 0) {
                (true, true) => 1e9 + k as f64,
                (true, false) => -1e9 - k as f64,
                _ => (k % 1000) as f64,
            })
            .collect();
        let (lo, hi) = (150, n - 151);
        let want = select_two_plainly(&d, lo, hi);
        let got = select_two(&mut d.clone(), lo, hi);
        assert_eq!((got.0.to_bits(), got.1.to_bits()), want);
        // And the ordinary case: the thresholds keep enough.
        let d: Vec<f64> = (0..n).map(|k| ((k * 7919) % n) as f64 * 0.5).collect();
        let got = select_two(&mut d.clone(), lo, hi);
        assert_eq!((got.0, got.1), (75.0, (n - 151) as f64 * 0.5));
    }

    #[test]
    fn a_block_keeps_its_farthest_valid_depth() {
        // 5 × 3 at step 2: blocks of 2 × 2, the last column and row partial.
        #[rustfmt::skip]
        let d = vec![
            1.0, 2.0,      0.0, f32::NAN, 7.0,
            3.0, 0.5,      -1.0, 0.0,     f32::INFINITY,
            4.0, f32::NAN, 0.0, 0.0,      6.0,
        ];
        let intr = Intrinsics::from_focal_px(5, 3, 10.0, None).unwrap();
        let s = DepthSnapshot::new(&metres(5, 3, d), &intr, 2);
        assert_eq!((s.cols, s.rows), (3, 2));
        assert_eq!(s.depth_m[0], 1.0);
        assert!(s.depth_m[1].is_nan(), "no return at the sample");
        assert_eq!(s.far_m[0], 3.0);
        assert!(s.far_m[1].is_nan(), "no valid pixel in the block");
        assert_eq!(s.far_m[2], f32::INFINITY, "sky is the farthest");
        assert_eq!(s.far_m[3], 4.0);
        assert!(s.far_m[4].is_nan());
        assert_eq!(s.far_m[5], 6.0);
    }

    /// The snapshot by its definition: every pixel converted to metres (NaN
    /// invalid), the sample at each block's top left and the `max` of the block.
    fn snapshot_by_definition(
        w: usize,
        h: usize,
        step: usize,
        px: &dyn Fn(usize) -> f32,
    ) -> (Vec<f32>, Vec<f32>) {
        let (cols, rows) = (w.div_ceil(step), h.div_ceil(step));
        let mut depth = vec![f32::NAN; cols * rows];
        let mut far = vec![f32::NAN; cols * rows];
        for r in 0..h {
            for c in 0..w {
                let b = (r / step) * cols + c / step;
                if r % step == 0 && c % step == 0 {
                    depth[b] = px(r * w + c);
                }
                far[b] = far[b].max(px(r * w + c));
            }
        }
        (depth, far)
    }

    #[test]
    fn the_one_pass_snapshot_equals_its_definition_bit_for_bit() {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 33) as u32
        };
        for (w, h) in [(1, 1), (5, 3), (17, 11), (64, 48), (93, 70)] {
            let intr = Intrinsics::from_focal_px(w, h, 50.0, None).unwrap();
            // Z16 with no-return and saturated pixels, runs of equal values,
            // and blocks that are all invalid.
            let z16: Vec<u16> = (0..w * h)
                .map(|k| match next() % 10 {
                    0 => 0,
                    1 => u16::MAX,
                    2 => 1000,
                    _ if k % 7 == 0 => 0,
                    _ => (next() % 65_536) as u16,
                })
                .collect();
            let scale_m = 0.001;
            let m: Vec<f32> = (0..w * h)
                .map(|_| match next() % 8 {
                    0 => f32::NAN,
                    1 => 0.0,
                    2 => -0.0,
                    3 => -(next() as f32),
                    4 => f32::INFINITY,
                    _ => next() as f32 * 1e-6,
                })
                .collect();
            for step in 1..=9 {
                let img = DepthImage::new(
                    w,
                    h,
                    DepthData::Z16 {
                        data: z16.clone(),
                        scale_m,
                    },
                )
                .unwrap();
                let s = DepthSnapshot::new(&img, &intr, step);
                let (d, f) = snapshot_by_definition(w, h, step, &|k| match z16[k] {
                    0 | u16::MAX => f32::NAN,
                    z => (z as f64 * scale_m) as f32,
                });
                assert_eq!(
                    (bits(&s.depth_m), bits(&s.far_m)),
                    (bits(&d), bits(&f)),
                    "Z16 {w}×{h} step {step}"
                );
                let s = DepthSnapshot::new(&metres(w, h, m.clone()), &intr, step);
                let (d, f) = snapshot_by_definition(w, h, step, &|k| {
                    if m[k] > 0.0 {
                        m[k]
                    } else {
                        f32::NAN
                    }
                });
                assert_eq!(
                    (bits(&s.depth_m), bits(&s.far_m)),
                    (bits(&d), bits(&f)),
                    "metres {w}×{h} step {step}"
                );
            }
        }
    }

    /// The unseen fraction by its definition: both captures asked for every
    /// sample (the function skips the second where the first sees it).
    fn unseen_by_definition(mid: &View, a: &View, b: &View) -> f64 {
        let (mut in_frustum, mut neither) = (0u64, 0u64);
        for r in 0..mid.depth.rows {
            for c in 0..mid.depth.cols {
                let Some((p, _)) = mid.point(c, r) else {
                    continue;
                };
                let (sa, sb) = (a.sees(p), b.sees(p));
                if sa == Sight::Outside && sb == Sight::Outside {
                    continue;
                }
                in_frustum += 1;
                let seen = |s| matches!(s, Sight::Seen | Sight::Unknown);
                if !seen(sa) && !seen(sb) {
                    neither += 1;
                }
            }
        }
        if in_frustum == 0 {
            0.0
        } else {
            neither as f64 / in_frustum as f64
        }
    }

    #[test]
    fn the_unseen_fraction_equals_its_definition() {
        // Blocks 10–25 m below a camera 30 m up, with gaps and invalid pixels,
        // seen from three positions along x and one rolled: every sight
        // (seen, hidden, outside, unknown) occurs.
        let (w, h) = (48, 36);
        let d: Vec<f32> = (0..w * h)
            .map(|k| {
                let (c, r) = (k % w, k / w);
                match (c / 6 + r / 9) % 5 {
                    0 => f32::NAN,
                    1 => 30.0,
                    k => 30.0 - 5.0 * k as f32,
                }
            })
            .collect();
        let intr = Intrinsics::from_focal_px(w, h, 40.0, None).unwrap();
        let view = |x: f64, roll: f64| View {
            depth: DepthSnapshot::new(&metres(w, h, d.clone()), &intr, 2),
            cam_to_ned: DMat3::from_rotation_z(roll),
            pos_ned_m: DVec3::new(x, 0.0, 0.0),
        };
        let views = [
            view(0.0, 0.0),
            view(1.5, 0.0),
            view(4.0, 0.0),
            view(2.0, 0.3),
        ];
        let mut fractions = Vec::new();
        for m in &views {
            for a in &views {
                for b in &views {
                    let f = unseen_fraction(m, a, b);
                    assert_eq!(f.to_bits(), unseen_by_definition(m, a, b).to_bits());
                    fractions.push(f);
                }
            }
        }
        assert!(
            fractions.iter().any(|&f| f > 0.0),
            "some view is partly unseen"
        );
    }

    #[test]
    fn a_surface_between_the_samples_is_seen() {
        // A wall at 10 m everywhere but one column at 30 m that no sample
        // (every fourth pixel) lands on: a point on it is seen through the
        // block's farthest depth, a point behind the wall elsewhere is not.
        let (w, h) = (16, 8);
        let d: Vec<f32> = (0..w * h)
            .map(|k| if k % w == 6 { 30.0 } else { 10.0 })
            .collect();
        let intr = Intrinsics::from_focal_px(w, h, 20.0, None).unwrap();
        let view = View {
            depth: DepthSnapshot::new(&metres(w, h, d), &intr, 4),
            cam_to_ned: DMat3::IDENTITY,
            pos_ned_m: DVec3::ZERO,
        };
        let (cx, cy) = intr.principal_px();
        let at = |u: f64, z: f64| DVec3::new((u - cx) / 20.0 * z, (4.5 - cy) / 20.0 * z, z);
        assert_eq!(view.sees(at(6.5, 30.0)), Sight::Seen);
        assert_eq!(view.sees(at(10.5, 30.0)), Sight::Hidden);
        assert_eq!(view.sees(at(10.5, 10.0)), Sight::Seen);
    }
}
