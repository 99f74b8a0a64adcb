//! The closed loop (DESIGN §1, issue 13): instead of predicting from one frame,
//! measure against the last capture. The capture's depth (decimated) is warped
//! into each frame's full 6-DoF pose: the parallax span between the two and the
//! fraction of an in-between frame that neither the capture nor the current
//! frame sees (what the next capture would leave unseen if taken now), and the
//! capture's points still short of `views_per_point_min` captures that the
//! frame loses or will lose one frame ahead. Pure: depth, poses and distances
//! are arguments.

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
    0.02 * depth_m + 0.05
}

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
        let (depth_m, far_m) = match image.data() {
            DepthData::Z16 { data, scale_m } => sample(w, h, step, |k| match data[k] {
                0 | u16::MAX => f32::NAN,
                z => (z as f64 * scale_m) as f32,
            }),
            DepthData::Metres(d) => sample(w, h, step, |k| {
                let z = d[k];
                if z > 0.0 {
                    z
                } else {
                    f32::NAN
                }
            }),
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

    /// The sample nearest the image point `(u, v)` (px), `None` outside the
    /// image.
    fn nearest(&self, u: f64, v: f64) -> Option<f32> {
        if !(u >= 0.0 && v >= 0.0 && u < self.width as f64 && v < self.height as f64) {
            return None;
        }
        let s = self.step as f64;
        let c = (((u - 0.5) / s).round().max(0.0) as usize).min(self.cols - 1);
        let r = (((v - 0.5) / s).round().max(0.0) as usize).min(self.rows - 1);
        Some(self.depth_m[r * self.cols + c])
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
        let (c0, r0) = (
            (x.floor() as usize).min(self.cols - 1),
            (y.floor() as usize).min(self.rows - 1),
        );
        let (c1, r1) = ((c0 + 1).min(self.cols - 1), (r0 + 1).min(self.rows - 1));
        let d = |c: usize, r: usize| self.depth_m[r * self.cols + c];
        // `u < width`, so the block is in range.
        let (bc, br) = (u as usize / self.step, v as usize / self.step);
        let far = self.far_m[br * self.cols + bc];
        Some([d(c0, r0), d(c1, r0), d(c0, r1), d(c1, r1), far])
    }
}

/// Every `step`-th pixel of a `w × h` frame, and the farthest of each block
/// (`metres(k)`: pixel `k` in metres, NaN invalid). One pass over the frame.
fn sample(w: usize, h: usize, step: usize, metres: impl Fn(usize) -> f32) -> (Vec<f32>, Vec<f32>) {
    let (cols, rows) = (w.div_ceil(step), h.div_ceil(step));
    let mut depth_m = Vec::with_capacity(cols * rows);
    for r in (0..h).step_by(step) {
        for c in (0..w).step_by(step) {
            depth_m.push(metres(r * w + c));
        }
    }
    // NaN never wins `max`, so a block keeps NaN only when all of it is invalid.
    let mut far_m = vec![f32::NAN; cols * rows];
    for r in 0..h {
        let blocks = &mut far_m[(r / step) * cols..][..cols];
        for (bc, far) in blocks.iter_mut().enumerate() {
            for c in bc * step..((bc + 1) * step).min(w) {
                *far = far.max(metres(r * w + c));
            }
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
        let Some((u, v, z)) = self.project(p) else {
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

impl View {
    /// Whether a camera at `to` would not see `p`, a point this view sees,
    /// judged from this view's depth alone: the segment from `p` to `to` is
    /// walked in this view's image, a sample at a time, and is blocked where
    /// the sample nearest its image shows a surface nearer than the segment
    /// (beyond the seen tolerance), i.e. where it passes behind what this view
    /// shows. Behind a surface counts as solid: what this view does not see it
    /// cannot call free. (The nearest sample, not any around as [`View::sees`]
    /// takes: the edge is where it is to half a sample, and a lenient test
    /// would call every segment within a sample of an edge free.) Where the
    /// walk leaves the image, or meets invalid depth, nothing blocks.
    fn blocked(&self, p: DVec3, to: DVec3) -> bool {
        let rt = self.cam_to_ned.transpose();
        let a = rt * (p - self.pos_ned_m);
        let b = rt * (to - p);
        if a.z.is_nan() || a.z <= 1e-9 {
            return false;
        }
        let (cx, cy) = self.depth.principal_px;
        let f = self.depth.focal_px;
        // The image point of `a + s·b` moves at `m / z(s)²` px per unit of
        // `s` (`z(s) = a.z + s·b.z`): a step `ds` moves it
        // `m·ds / (z·(z + ds·b.z))`, one sample when `ds` is as below.
        let m = f * (b.x * a.z - a.x * b.z).hypot(b.y * a.z - a.y * b.z);
        if !(m > 0.0 && m.is_finite()) {
            // Along this view's own ray to `p`, which it sees: free.
            return false;
        }
        let step_px = self.depth.step as f64;
        let mut s = 0.0;
        // At most one visit per sample of the longest image line, and then some.
        for _ in 0..4 * (self.depth.cols + self.depth.rows) {
            let z = a.z + s * b.z;
            let denom = m - step_px * z * b.z;
            if !(z > 1e-9 && denom > 0.0) {
                return false;
            }
            s += step_px * z * z / denom;
            if s >= 1.0 {
                return false;
            }
            let q = a + b * s;
            if q.z.is_nan() || q.z <= 1e-9 {
                return false;
            }
            let Some(d) = self.depth.nearest(cx + f * q.x / q.z, cy + f * q.y / q.z) else {
                return false;
            };
            let (valid, free) = (!d.is_nan(), d as f64 >= q.z - seen_tolerance_m(q.z));
            if valid && !free {
                return true;
            }
        }
        false
    }

    /// For a point `p` (NED) this view sees: how much further the camera can
    /// move by `step_m` (NED, one frame's travel) with `p` still in its frame
    /// and not behind what this view shows ([`View::blocked`]), m, looking at
    /// most [`LOOKAHEAD_STEPS`] steps ahead (`None`: kept that far, or this
    /// view does not see `p`). Doubling from one step, then halving the
    /// bracket to half a step; the kept end is returned (a capture there still
    /// sees `p`). One frame's travel moves an occluder's edge by a fraction of
    /// a pixel, so a single step ahead cannot be judged from a depth map: the
    /// distance is, to about a pixel of the edge's image motion.
    pub fn remaining_m(&self, p: DVec3, step_m: DVec3) -> Option<f64> {
        if self.sees(p) != Sight::Seen {
            return None;
        }
        let len = step_m.length();
        if !(len > 0.0 && len.is_finite()) {
            return None;
        }
        let lost = |k: f64| {
            let at = self.pos_ned_m + step_m * k;
            !self.in_frame_from(p, at) || self.blocked(p, at)
        };
        let (mut kept, mut gone) = (0.0, None);
        let mut k = 1.0;
        while k <= LOOKAHEAD_STEPS as f64 {
            if lost(k) {
                gone = Some(k);
                break;
            }
            kept = k;
            k *= 2.0;
        }
        let mut gone = gone?;
        while gone - kept > 0.5 {
            let mid = 0.5 * (kept + gone);
            if lost(mid) {
                gone = mid;
            } else {
                kept = mid;
            }
        }
        Some(kept * len)
    }

    /// Whether `p` lies inside this view's frame were the camera at `pos`
    /// (same attitude).
    fn in_frame_from(&self, p: DVec3, pos: DVec3) -> bool {
        let q = self.cam_to_ned.transpose() * (p - pos);
        if q.z.is_nan() || q.z <= 1e-9 {
            return false;
        }
        let (cx, cy) = self.depth.principal_px;
        let f = self.depth.focal_px;
        let (u, v) = (cx + f * q.x / q.z, cy + f * q.y / q.z);
        u >= 0.0 && v >= 0.0 && u < self.depth.width as f64 && v < self.depth.height as f64
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
            match a.sees(p) {
                Sight::Outside | Sight::Unknown => {}
                Sight::Hidden => {
                    inside += 1;
                    hidden += 1;
                }
                Sight::Seen => {
                    inside += 1;
                    // Against the same ray at infinity: rotation gives no parallax.
                    if let (Some((u, v, _)), Some((ui, vi, _))) =
                        (a.project(p), a.project(a.pos_ned_m + ray))
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
    if d.is_empty() {
        return None;
    }
    let n = d.len();
    let lo = ((n - 1) as f64 * PARALLAX_PERCENTILES.0).round() as usize;
    let hi = ((n - 1) as f64 * PARALLAX_PERCENTILES.1).round() as usize;
    let q_hi = *d.select_nth_unstable_by(hi, f64::total_cmp).1;
    let q_lo = *d[..=hi]
        .select_nth_unstable_by(lo.min(hi), f64::total_cmp)
        .1;
    Some(q_hi - q_lo)
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

/// How many frames ahead [`View::remaining_m`] looks (a power of two).
pub const LOOKAHEAD_STEPS: u32 = 16;

/// Earlier captures the closed loop keeps for the views-per-point count:
/// a point seen by all of them counts as held by `views_per_point_min − 1`
/// captures even where that is more (so `views_per_point_min` above
/// `EARLIER_CAPTURES_MAX + 1` is held as `EARLIER_CAPTURES_MAX + 1`).
pub const EARLIER_CAPTURES_MAX: usize = 8;

/// The capture's points the next capture must also see, and how many of them
/// a frame has lost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ViewsAtRisk {
    /// The capture's surface samples in the middle half across track (the
    /// views bound's band, as the open loop's and the truth's) that fewer than
    /// `k − 1` earlier captures see: short of `k` captures unless the next
    /// capture sees them too.
    pub needed: u64,
    /// Of those, the ones the frame no longer sees (hidden or out of its
    /// frame): a capture now is too late for them.
    pub lost: u64,
    /// The ones the frame still sees but a camera one frame ahead would not
    /// (out of its frame, or behind what this frame shows): a capture now
    /// holds them, the next frame's would not.
    pub at_risk: u64,
    /// The least travel, m, before the frame loses one of those it still
    /// sees ([`View::remaining_m`]; `None`: none within the look-ahead).
    pub remaining_m: Option<f64>,
}

/// The capture `capture`'s points short of `k` captures (`earlier`: the
/// captures before it, newest first) against the frame `frame`, whose next
/// frame is `ahead_m` further (NED, m). Samples an invalid depth leaves
/// undecided count as seen, as in [`unseen_fraction`]: missing depth must not
/// trigger captures.
pub fn views_at_risk(
    capture: &View,
    earlier: &[View],
    k: u32,
    frame: &View,
    ahead_m: DVec3,
) -> ViewsAtRisk {
    let mut out = ViewsAtRisk::default();
    if k < 2 {
        return out;
    }
    // Held by this many earlier captures, the capture makes `k` (capped: see
    // [`EARLIER_CAPTURES_MAX`]). Early in a flight there are fewer: short.
    let enough = (k as usize - 1).min(EARLIER_CAPTURES_MAX);
    let earlier = &earlier[..earlier.len().min(enough)];
    // Across track is the image axis the motion runs less along.
    let dir = capture.cam_to_ned.transpose() * ahead_m;
    let along_columns = dir.x.abs() >= dir.y.abs();
    let d = &capture.depth;
    for r in 0..d.rows {
        for c in 0..d.cols {
            let (u, v) = (c * d.step, r * d.step);
            let in_band = if along_columns {
                v >= d.height / 4 && v < d.height - d.height / 4
            } else {
                u >= d.width / 4 && u < d.width - d.width / 4
            };
            if !in_band {
                continue;
            }
            let Some((p, _)) = capture.point(c, r) else {
                continue;
            };
            let held = earlier
                .iter()
                .filter(|e| matches!(e.sees(p), Sight::Seen | Sight::Unknown))
                .count();
            if held >= enough {
                continue;
            }
            out.needed += 1;
            match frame.sees(p) {
                Sight::Unknown => {}
                Sight::Hidden | Sight::Outside => out.lost += 1,
                Sight::Seen => {
                    if let Some(rem) = frame.remaining_m(p, ahead_m) {
                        out.remaining_m = Some(out.remaining_m.map_or(rem, |m: f64| m.min(rem)));
                        // Kept for less than one frame's travel: lost by the next.
                        out.at_risk += (rem < ahead_m.length()) as u64;
                    }
                }
            }
        }
    }
    out
}

/// The targets the closed loop holds (the quality model's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosedLoopTargets {
    pub parallax_px: Option<f64>,
    pub unseen_fraction_max: f64,
    /// Every point in at least this many captures (1: no views bound).
    pub views_per_point_min: u32,
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
    /// The last capture's points short of `views_per_point_min` captures,
    /// and how many of them this frame lost or will lose one frame ahead.
    pub views: ViewsAtRisk,
    /// The largest spacing the measurements allow, extrapolated one frame
    /// ahead (`None`: no target is near).
    pub spacing_m: Option<f64>,
    /// Which target sets `spacing_m`: `parallax`, `unseen_fraction` or
    /// `views_per_point`.
    pub bound: Option<&'static str>,
}

/// The closed loop's state: the last capture and the frames since.
#[derive(Debug, Clone, Default)]
pub struct ClosedLoop {
    capture: Option<(View, f64)>,
    /// The captures before it, newest first, at most [`EARLIER_CAPTURES_MAX`].
    earlier: Vec<View>,
    kept: Vec<(View, f64)>,
    last: Option<Measure>,
}

impl ClosedLoop {
    /// A capture was taken at `view`, at odometer reading `odometer_m`.
    pub fn on_capture(&mut self, view: View, odometer_m: f64) {
        if let Some((old, _)) = self.capture.take() {
            self.earlier.insert(0, old);
            self.earlier.truncate(EARLIER_CAPTURES_MAX);
        }
        self.capture = Some((view, odometer_m));
        self.kept.clear();
        self.last = None;
    }

    /// Measures `view` (at `odometer_m`) against the last capture; `ahead_m`
    /// is the travel to the next frame (NED, m; its horizontal length is the
    /// odometer's step). `None` before the first capture.
    pub fn on_frame(
        &mut self,
        view: View,
        odometer_m: f64,
        ahead_m: DVec3,
        t: &ClosedLoopTargets,
    ) -> Option<Measure> {
        let ahead_m = if ahead_m.is_finite() {
            ahead_m
        } else {
            DVec3::ZERO
        };
        let next_step_m = ahead_m.x.hypot(ahead_m.y);
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
        let views = views_at_risk(cap, &self.earlier, t.views_per_point_min, &view, ahead_m);
        let step = next_step_m;
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
        // The first point short of the views target that the frame will
        // lose: capture before it is. (The ones already lost a capture
        // cannot bring back.)
        if let Some(rem) = views.remaining_m {
            offer(d + rem, "views_per_point");
        }
        let m = Measure {
            distance_m: d,
            parallax_px: p.parallax_span_px,
            unseen_fraction: unseen,
            in_view_fraction: p.in_view_fraction,
            views,
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

    fn metres(w: usize, h: usize, d: Vec<f32>) -> DepthImage {
        DepthImage::new(w, h, DepthData::Metres(d)).unwrap()
    }

    /// A thin plate 10 m below a nadir camera (north 2–4 m, every east) over
    /// ground at 20 m; image x is north, `f` = 32 px, 64 × 48. The ground
    /// under the plate's near edge is seen under it; flying north the ray
    /// meets the plate's underside, flying south never.
    fn plate_view() -> View {
        let (w, h, f) = (64, 48, 32.0);
        let d: Vec<f32> = (0..w * h)
            .map(|k| {
                let t = ((k % w) as f64 + 0.5 - 32.0) / f;
                if (0.2..=0.4).contains(&t) {
                    10.0
                } else {
                    20.0
                }
            })
            .collect();
        let intr = Intrinsics::from_focal_px(w, h, f, None).unwrap();
        View {
            depth: DepthSnapshot::new(&metres(w, h, d), &intr, 1),
            cam_to_ned: DMat3::IDENTITY,
            pos_ned_m: DVec3::ZERO,
        }
    }

    #[test]
    fn the_look_ahead_finds_the_plates_underside_to_a_pixel() {
        let v = plate_view();
        // Pixel 37's ground point: north 20·(37.5 − 32)/32 = 3.4375 m, seen
        // under the plate. The truth loses it flying north once the ray at
        // 10 m passes the edge: (δ + 3.4375)/2 ≥ 2, δ ≥ 0.5625 m. The depth
        // map puts the edge at pixel 38's boundary (t = 0.203 against 0.2)
        // and asks the segment to be the seen tolerance behind the plate:
        // about 0.63 m (see the comment at `blocked`), to half a step.
        let (u, z) = (37.5, 20.0);
        let p = DVec3::new(z * (u - 32.0) / 32.0, z * (24.5 - 24.0) / 32.0, z);
        let north = DVec3::new(0.05, 0.0, 0.0);
        let rem = v.remaining_m(p, north).expect("lost within 16 steps");
        assert!((0.55..=0.70).contains(&rem), "north: {rem} m");
        // Flying south the ray steepens away from the plate; the frame edge is
        // 6 m away, beyond the look-ahead.
        assert_eq!(v.remaining_m(p, -north), None);
        // A ground point far from the plate: nothing within the look-ahead.
        let q = DVec3::new(z * (10.5 - 32.0) / 32.0, 0.0, z);
        assert_eq!(v.remaining_m(q, north), None);
        // Not seen (behind the plate): no look-ahead.
        let hidden = DVec3::new(20.0 * 0.3, 0.0, 20.0);
        assert_eq!(v.remaining_m(hidden, north), None);
        // Hovering: nothing is lost.
        assert_eq!(v.remaining_m(p, DVec3::ZERO), None);
    }

    #[test]
    fn flat_ground_is_never_lost_but_at_the_frame_edge() {
        let (w, h, f) = (64, 48, 32.0);
        let intr = Intrinsics::from_focal_px(w, h, f, None).unwrap();
        let v = View {
            depth: DepthSnapshot::new(&metres(w, h, vec![20.0; w * h]), &intr, 1),
            cam_to_ned: DMat3::IDENTITY,
            pos_ned_m: DVec3::ZERO,
        };
        let step = DVec3::new(0.1, 0.03, 0.0);
        for c in 0..w {
            let p = DVec3::new(20.0 * (c as f64 + 0.5 - 32.0) / 32.0, 0.0, 20.0);
            let rem = v.remaining_m(p, step);
            // The frame's back edge (north −20 m at this depth) is the only loss.
            let to_edge_m = p.x + 20.0;
            let len = step.length();
            match rem {
                Some(r) => assert!(
                    r <= to_edge_m / (step.x / len) && r > to_edge_m / (step.x / len) - 0.6 * len,
                    "column {c}: lost after {r} m, edge at {to_edge_m} m north"
                ),
                None => assert!(
                    to_edge_m / (step.x / len) > 15.0 * len,
                    "column {c}: kept, edge at {to_edge_m} m north"
                ),
            }
        }
    }

    #[test]
    fn views_at_risk_counts_what_no_earlier_capture_holds() {
        let v = plate_view();
        let north = DVec3::new(0.05, 0.0, 0.0);
        // k = 1: no views bound.
        assert_eq!(views_at_risk(&v, &[], 1, &v, north), ViewsAtRisk::default());
        // k = 2, no earlier capture: every sample of the middle half needs the
        // next one; the frame is the capture itself, so none is lost yet.
        let r = views_at_risk(&v, &[], 2, &v, north);
        assert_eq!(r.needed, 64 * 24);
        assert_eq!(r.lost, 0);
        // The back edge's column goes first: its ground (north −19.6875 m)
        // leaves the frame (north −20 m) after 0.3125 m, to half a step.
        let rem = r.remaining_m.expect("the back edge");
        assert!((0.3125 - 0.025..=0.3125).contains(&rem), "{rem}");
        // An earlier capture at the same place holds everything it sees.
        let held = views_at_risk(&v, std::slice::from_ref(&v), 2, &v, north);
        assert_eq!(held.needed, 0);
        assert_eq!(held.remaining_m, None);
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
