//! The visibility term (DESIGN §1, issue 13): each surface sample's interval of
//! camera positions along track from which it is visible (a horizon sweep per
//! line), and from the intervals the unseen fraction against spacing and the
//! views per point. Invariant: every interval holds 0 (the current camera).

use super::depth::{DepthImage, Intrinsics, TrackAxis, TrackGeometry, HORIZON_EPS};
use super::inverse::{fill_grid, DepthRange, InvGrid, INVALID, SKY};

/// Interior phases of the in-between view when none is configured.
pub const DEFAULT_PHASES: usize = 15;

/// The targets and the knobs of the term.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisibilityParams {
    /// Largest fraction of the mid view's surface samples neither neighbouring
    /// capture may miss (`[quality] unseen_fraction_max`).
    pub unseen_fraction_max: f64,
    /// Captures every visible surface point must be in (`views_per_point_min`).
    pub views_per_point_min: u32,
    /// Positions of the in-between view between its two captures: `s = i/(P+1)`,
    /// `i = 1..=P`. The worst of them is reported. Against every phase in
    /// `(0, 1)`, the fraction at `b` is at least the continuum's worst at
    /// `b/(1 + 1/P)`, and a point's onset spacing is at most `(1 + 1/P)·L`.
    pub phases: usize,
    /// Relative depth margin an occluder must clear (0: exact geometry).
    pub occluder_margin_rel: f64,
    /// Middle fraction of the lines across track whose samples set the views
    /// per point (1: all). Off the middle the 2-D line model leaves out
    /// occluders beside the line, and points at the lateral edges are side
    /// overlap's business, not the spacing's (the truth samples the middle half).
    pub views_band: f64,
}

impl Default for VisibilityParams {
    fn default() -> Self {
        VisibilityParams {
            unseen_fraction_max: 0.002,
            views_per_point_min: 2,
            phases: DEFAULT_PHASES,
            occluder_margin_rel: 1e-3,
            views_band: 1.0,
        }
    }
}

/// What bounds one end of a visibility interval.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// A sample of the frame that the ray to the camera meets.
    Occluder,
    /// The camera's along-track field of view (possibly never: an infinite end).
    Frustum,
}

/// Camera positions along the line, metres from the current camera, from which
/// a surface sample is visible: `from_m ≤ 0 ≤ to_m` (the current camera sees it).
/// Ends may be infinite (a frustum that never loses the point).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub from_m: f64,
    pub to_m: f64,
    pub from: End,
    pub to: End,
}

impl Interval {
    /// `L`, metres: the truth's `point_spacing` for one interval is `L / k`.
    pub fn length_m(&self) -> f64 {
        self.to_m - self.from_m
    }

    /// Whether an occluder (not only the field of view) cuts it.
    pub fn occluded(&self) -> bool {
        self.from == End::Occluder || self.to == End::Occluder
    }

    /// Whether the camera at `c_m` sees the sample (closed interval).
    pub fn contains(&self, c_m: f64) -> bool {
        self.from_m <= c_m && c_m <= self.to_m
    }
}

/// Which side of the flight line a sample's ray points to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Below,
    Above,
    Horizon,
}

/// The per-sample constants of the along-track rays of one frame geometry.
#[derive(Debug, Clone)]
pub struct TrackRays {
    side: Vec<Side>,
    /// Samples below the flight line in increasing `X` (pixel order), and the
    /// mirrored ones above it (reverse pixel order).
    below: Vec<usize>,
    above: Vec<usize>,
    /// `X = x/|h|` of the ray (mirrored above the line).
    x: Vec<f64>,
    /// `1/|cos φ − t·sin φ|`: `Y = w · inv_g`.
    inv_g: Vec<f64>,
    /// The along-track frustum in camera positions per metre of depth: the
    /// sample at depth `d` stays in view for `c ∈ d·[f_lo, f_hi]`.
    f_lo: Vec<f64>,
    f_hi: Vec<f64>,
}

/// `a·u ≥ b` as a range of `u` (`None`: empty).
fn half_line_ge(a: f64, b: f64) -> Option<(f64, f64)> {
    if a > 0.0 {
        Some((b / a, f64::INFINITY))
    } else if a < 0.0 {
        Some((f64::NEG_INFINITY, b / a))
    } else if b <= 0.0 {
        Some((f64::NEG_INFINITY, f64::INFINITY))
    } else {
        None
    }
}

impl TrackRays {
    /// The rays of the samples at original along-track pixel indices `along_idx`.
    /// A non-finite pitch gives no surface sample at all.
    pub fn new(geom: &TrackGeometry, along_idx: &[usize], pitch_rad: f64) -> TrackRays {
        let n = along_idx.len();
        let mut rays = TrackRays {
            side: vec![Side::Horizon; n],
            below: Vec::new(),
            above: Vec::new(),
            x: vec![0.0; n],
            inv_g: vec![0.0; n],
            f_lo: vec![0.0; n],
            f_hi: vec![0.0; n],
        };
        let f = geom.focal_px;
        if !(pitch_rad.is_finite() && f.is_finite() && f > 0.0) {
            return rays;
        }
        let (sp, cp) = pitch_rad.sin_cos();
        // The image edges along track as angles from nadir (forward positive).
        let t_min = -geom.c_along_px / f;
        let t_max = (geom.along_px as f64 - geom.c_along_px) / f;
        let (sa0, ca0) = (pitch_rad + t_min.atan()).sin_cos();
        let (sa1, ca1) = (pitch_rad + t_max.atan()).sin_cos();
        for (j, &i) in along_idx.iter().enumerate() {
            // On the horizon (`|g|` at most `HORIZON_EPS`): neither below nor
            // above the flight line, left out.
            let t = geom.v_px(i) / f;
            let g = geom.ray_down(i, sp, cp);
            let xr = sp + t * cp;
            rays.side[j] = if g > HORIZON_EPS {
                Side::Below
            } else if g < -HORIZON_EPS {
                Side::Above
            } else {
                continue;
            };
            rays.inv_g[j] = 1.0 / g.abs();
            rays.x[j] = xr / g.abs();
            // In view from `c` iff the direction `(u, h) = (x − c, h)` lies
            // between the edge rays `(sin α, cos α)`: `cos α₀·u ≥ sin α₀·h` and
            // `cos α₁·u ≤ sin α₁·h` (the cone is narrower than π). Per metre
            // of depth, `x = xr` and `h = g`.
            let a = half_line_ge(ca0, sa0 * g);
            let b = half_line_ge(-ca1, -sa1 * g);
            let (lo, hi) = match (a, b) {
                (Some(a), Some(b)) => (a.0.max(b.0), a.1.min(b.1)),
                _ => (0.0, 0.0),
            };
            // `c = x − u`; the sample itself is in view from `c = 0`.
            rays.f_lo[j] = (xr - hi).min(0.0);
            rays.f_hi[j] = (xr - lo).max(0.0);
        }
        rays.below = (0..n).filter(|&j| rays.side[j] == Side::Below).collect();
        rays.above = (0..n)
            .rev()
            .filter(|&j| rays.side[j] == Side::Above)
            .collect();
        rays
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// Reusable buffers of the per-line sweep.
#[derive(Debug, Clone, Default)]
pub struct LineScratch {
    /// `X` and `Y` of the run's surface samples, increasing `X`.
    xs: Vec<f64>,
    ys: Vec<f64>,
    idx: Vec<usize>,
    /// The along-track frustum of each, camera positions in metres.
    frustum_lo_m: Vec<f64>,
    frustum_hi_m: Vec<f64>,
    ahead: Vec<f64>,
    hull: Hull,
}

/// Points per block of [`sweep`]'s floor.
const FLOOR_BLOCK: usize = 32;

/// Room for [`sweep`]'s hull; contents are the sweep's own.
#[derive(Debug, Clone, Default)]
struct Hull {
    /// The hull's vertices (`X`, `Y`) as a stack: the sweep keeps its length.
    x: Vec<f64>,
    y: Vec<f64>,
    /// Per block of points, at most the lowest lifted `Y` of the points swept
    /// after any of them.
    floor: Vec<f64>,
}

/// For points sorted by increasing `X` (`(xs[i], ys[i]) = (X, Y)`), the camera
/// position beyond which each is hidden (`+∞`: no point on that side rises
/// above it): the tangent from the point (lifted by `margin` in `Y`) to the upper
/// hull of the points after it (`BEHIND = false`), or, mirrored (`X → −X`),
/// before it (`BEHIND = true`, reported as the magnitude). Given as `put(i, c)`,
/// once per point, in sweep order (`BEHIND`: increasing `i`).
///
/// A point no later point's lifted self lies under (`Y ≤` the `floor` of the
/// points swept after it) is never anyone's tangent with `dy > 0`, so it stays
/// off the hull: on open ground, whose depth noise is under the margin, the
/// hull holds only what rises above it. Its own tangent is then found by the
/// walk over the hull as it is (the chain is strictly concave, so the slopes
/// from a point before it rise, then fall), from the vertex the last walk
/// found: a run of ground before a wall asks for the same vertex again and
/// again.
fn sweep<const BEHIND: bool>(
    xs: &[f64],
    ys: &[f64],
    margin: f64,
    hull: &mut Hull,
    mut put: impl FnMut(usize, f64),
) {
    let n = xs.len().min(ys.len());
    let lift = 1.0 + margin;
    // A lower bound of the floor is as good (more points stay on the hull):
    // per block of points, the least lifted `Y` of the block and of every block
    // swept after it, found without a chain of dependent minima per point.
    let blocks = n.div_ceil(FLOOR_BLOCK);
    hull.floor.clear();
    hull.floor.extend(ys.chunks(FLOOR_BLOCK).map(|c| {
        let m = c
            .iter()
            .fold(f64::INFINITY, |m, &y| if y < m { y } else { m });
        m * lift
    }));
    let floor = &mut hull.floor[..blocks];
    if BEHIND {
        for b in (0..blocks.saturating_sub(1)).rev() {
            floor[b] = floor[b].min(floor[b + 1]);
        }
    } else {
        for b in 1..blocks {
            floor[b] = floor[b].min(floor[b - 1]);
        }
    }
    // The hull as a stack in two fixed slices and a length: no capacity check
    // per push, and `X`, `Y` loaded apart (a pair written one iteration and
    // read back the next stalls on store forwarding).
    if hull.x.len() < n {
        hull.x.resize(n, 0.0);
        hull.y.resize(n, 0.0);
    }
    let (hx, hy) = (&mut hull.x[..n], &mut hull.y[..n]);
    let mut len = 0usize;
    let sign = if BEHIND { -1.0 } else { 1.0 };
    // `slope(P, a) ≤ slope(P, b)` for `a`, `b` beyond `P`, without dividing.
    #[inline(always)]
    fn not_above(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> bool {
        (a.1 - p.1) * (b.0 - p.0) <= (b.1 - p.1) * (a.0 - p.0)
    }
    // The highest `Y` of the points beyond `p` (all swept so far).
    let mut y_beyond = f64::NEG_INFINITY;
    // The top of the stack, also kept in registers.
    let mut last = (0.0, 0.0);
    // Stack index of the last tangent found by the walk.
    let mut tangent_at = usize::MAX;
    for k in 0..n {
        let i = if BEHIND { k } else { n - 1 - k };
        let p = (sign * xs[i], ys[i]);
        let on_hull = p.1 > floor[i / FLOOR_BLOCK];
        // The hull of the points beyond `p`, seen from `p`: what lies on or
        // under the chord from `p` to the next vertex is no one's tangent.
        while on_hull && len >= 2 {
            let b = (hx[len - 2], hy[len - 2]);
            if not_above(p, last, b) {
                len -= 1;
                last = b;
            } else {
                break;
            }
        }
        let pl = (p.0, p.1 * lift);
        let mut hidden_beyond = f64::INFINITY;
        // Otherwise nothing beyond rises above the lifted point, so no tangent
        // has `dy > 0` and this side stays open (open ground, roofs): the walk
        // below would find the same. (`Y` is finite: no NaN to compare.)
        if pl.1 < y_beyond {
            let tangent = if (margin > 0.0 || !on_hull) && len >= 2 {
                // From the lifted point (or one the hull was not popped for)
                // the tangent lies at or beyond the top: slopes along the
                // chain rise, then fall. A small lift moves it a vertex or
                // two: walk a few, then bisect the rest.
                // Chain order: c = 0 is the top (nearest), stack index top−c.
                let top = len - 1;
                let at = |c: usize| {
                    if c == 0 {
                        last
                    } else {
                        (hx[top - c], hy[top - c])
                    }
                };
                // `q(c)`: the tangent is at `c` or nearer; false, then true
                // along the chain (the first true is the tangent; the farthest
                // vertex has nothing after it).
                let q = |c: usize| c >= top || not_above(pl, at(c + 1), at(c));
                // The points off the hull between two changes of it query the
                // same chain, mostly for the same vertex: start from the last
                // answer if it is still on the stack, walk a few, bisect the rest.
                let mut lo = top.saturating_sub(tangent_at);
                let first_true = |mut lo: usize, mut hi: usize| {
                    while lo < hi {
                        let mid = (lo + hi) / 2;
                        if q(mid) {
                            hi = mid;
                        } else {
                            lo = mid + 1;
                        }
                    }
                    lo
                };
                if q(lo) {
                    let mut steps = 0;
                    while lo > 0 && q(lo - 1) {
                        lo -= 1;
                        steps += 1;
                        if steps == 4 {
                            lo = first_true(0, lo);
                            break;
                        }
                    }
                } else {
                    let mut steps = 0;
                    loop {
                        lo += 1;
                        if q(lo) {
                            break;
                        }
                        steps += 1;
                        if steps == 4 {
                            lo = first_true(lo + 1, top);
                            break;
                        }
                    }
                }
                tangent_at = top - lo;
                Some(at(lo))
            } else {
                (len > 0).then_some(last)
            };
            if let Some(q) = tangent {
                let dy = q.1 - pl.1;
                if dy > 0.0 {
                    hidden_beyond = (q.0 - p.0).max(0.0) / dy;
                }
            }
        }
        put(i, hidden_beyond);
        if on_hull {
            hx[len] = p.0;
            hy[len] = p.1;
            len += 1;
            last = p;
        }
        y_beyond = y_beyond.max(p.1);
    }
}

/// Sweeps one run of samples (sorted by `X`) both ways and emits each interval.
fn sweep_run(margin: f64, s: &mut LineScratch, emit: &mut impl FnMut(usize, Interval)) {
    if s.xs.is_empty() {
        return;
    }
    let n = s.xs.len();
    s.ahead.resize(n, f64::INFINITY);
    let ahead = &mut s.ahead[..n];
    sweep::<false>(&s.xs, &s.ys, margin, &mut s.hull, |i, v| ahead[i] = v);
    let ahead = &s.ahead[..n];
    let (lo_m, hi_m, idx) = (&s.frustum_lo_m[..n], &s.frustum_hi_m[..n], &s.idx[..n]);
    // Behind goes in increasing index: each interval is complete as its
    // point is swept.
    sweep::<true>(&s.xs, &s.ys, margin, &mut s.hull, |k, behind| {
        let j = idx[k];
        let (f_lo, f_hi) = (lo_m[k], hi_m[k]);
        let (o_lo, o_hi) = (-behind, ahead[k]);
        let (from_m, from) = if o_lo > f_lo {
            (o_lo, End::Occluder)
        } else {
            (f_lo, End::Frustum)
        };
        let (to_m, to) = if o_hi < f_hi {
            (o_hi, End::Occluder)
        } else {
            (f_hi, End::Frustum)
        };
        emit(
            j,
            Interval {
                from_m: from_m.min(0.0),
                to_m: to_m.max(0.0),
                from,
                to,
            },
        );
    });
}

/// Calls `emit(j, interval)` for every surface sample `j` of one line of
/// inverse depths (`INVALID` < 0, `SKY` = 0, else 1/m), in no fixed order.
pub fn sweep_line(
    line: &[f32],
    rays: &TrackRays,
    margin_rel: f64,
    s: &mut LineScratch,
    mut emit: impl FnMut(usize, Interval),
) {
    let margin = if margin_rel.is_finite() {
        margin_rel.max(0.0)
    } else {
        0.0
    };
    // Below the line `X` grows with the pixel index, above it (mirrored) it
    // falls: each run is visited in increasing `X`.
    for order in [&rays.below, &rays.above] {
        // Every sample written, the count moved by the valid ones: no branch
        // to mispredict at the edges of sky and invalid runs.
        let m = order.len();
        s.xs.resize(m, 0.0);
        s.ys.resize(m, 0.0);
        s.idx.resize(m, 0);
        s.frustum_lo_m.resize(m, 0.0);
        s.frustum_hi_m.resize(m, 0.0);
        // Slices held apart, so that a store does not make the compiler load
        // the vectors' pointers again.
        let (xs, ys, idx) = (&mut s.xs[..m], &mut s.ys[..m], &mut s.idx[..m]);
        let (lo_m, hi_m) = (&mut s.frustum_lo_m[..m], &mut s.frustum_hi_m[..m]);
        let (ray_x, inv_g) = (&rays.x[..], &rays.inv_g[..]);
        let (f_lo, f_hi) = (&rays.f_lo[..], &rays.f_hi[..]);
        let mut c = 0;
        for (k, &j) in order.iter().enumerate() {
            // Outside the line (a ray table longer than the line): invalid.
            let w = line.get(j).copied().unwrap_or(INVALID);
            // `c <= k` always, so the `min` changes nothing: it bounds the
            // index by `k < m` for the compiler.
            let c_at = c.min(k);
            xs[c_at] = ray_x[j];
            ys[c_at] = w as f64 * inv_g[j];
            idx[c_at] = j;
            // Depth, metres (a branch-free loop keeps the divisions in flight).
            let d = 1.0 / w as f64;
            lo_m[c_at] = d * f_lo[j];
            hi_m[c_at] = d * f_hi[j];
            // Valid and not sky, `0 < w < ∞` (NaN fails both).
            c += (w > SKY && w < f32::INFINITY) as usize;
        }
        s.xs.truncate(c);
        s.ys.truncate(c);
        s.idx.truncate(c);
        s.frustum_lo_m.truncate(c);
        s.frustum_hi_m.truncate(c);
        sweep_run(margin, s, &mut emit);
    }
}

/// The intervals of one line, one entry per sample (`None`: invalid, sky, or on
/// the camera's horizon).
pub fn line_intervals(
    line: &[f32],
    rays: &TrackRays,
    margin_rel: f64,
    scratch: &mut LineScratch,
    out: &mut Vec<Option<Interval>>,
) {
    out.clear();
    out.resize(line.len(), None);
    sweep_line(line, rays, margin_rel, scratch, |j, iv| out[j] = Some(iv));
}

/// The visibility term of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Visibility {
    /// Lines with at least one surface sample.
    pub lines: u64,
    /// Surface samples (valid, not sky, off the camera's horizon): the
    /// denominator of the unseen fraction.
    pub samples: u64,
    /// Samples whose interval an occluder cuts on at least one side: the only
    /// ones that can fall between two captures.
    pub occluded_samples: u64,
    /// Lines with at least one occluded sample (0: the term is left out).
    pub occluded_lines: u64,
    /// Shortest interval of any surface sample in the views band, m.
    pub interval_min_m: Option<f64>,
    /// Shortest interval of an occluded sample in the views band, m.
    pub occluded_interval_min_m: Option<f64>,
    /// Largest spacing whose unseen fraction is at most the target (`None`:
    /// no spacing exceeds it: too few occluded samples).
    pub spacing_unseen_m: Option<f64>,
    /// `min L / k` over all surface samples: every visible point in at least `k`
    /// captures whatever the phase. Frustum-limited samples count (their `L` is
    /// the footprint, the overlap for `k` views).
    pub spacing_views_m: Option<f64>,
    /// The same over occluded samples only (what the occluders add to overlap).
    pub spacing_views_occluded_m: Option<f64>,
    pub unseen_fraction_max: f64,
    pub views_per_point_min: u32,
    phases: usize,
    /// `(from, to)` of every occluded sample, m.
    occluded: Vec<(f32, f32)>,
}

impl Visibility {
    fn empty(params: &VisibilityParams) -> Visibility {
        Visibility {
            lines: 0,
            samples: 0,
            occluded_samples: 0,
            occluded_lines: 0,
            interval_min_m: None,
            occluded_interval_min_m: None,
            spacing_unseen_m: None,
            spacing_views_m: None,
            spacing_views_occluded_m: None,
            unseen_fraction_max: sanitize_fraction(params.unseen_fraction_max),
            views_per_point_min: params.views_per_point_min.max(1),
            phases: params.phases.max(1),
            occluded: Vec::new(),
        }
    }

    /// Whether any line has an occluder (otherwise the term says nothing the
    /// coverage bound does not).
    pub fn has_occluders(&self) -> bool {
        self.occluded_samples > 0
    }

    /// The phases `s` of the in-between view (captures at `−s·b`, `(1−s)·b`).
    pub fn phases(&self) -> impl Iterator<Item = f64> {
        let p = self.phases;
        (1..=p).map(move |i| i as f64 / (p + 1) as f64)
    }

    /// Predicted unseen fraction of the in-between view at spacing `b`: this
    /// frame stands for the view, its two neighbouring captures at `−s·b` and
    /// `(1 − s)·b`; the fraction of its surface samples neither sees, worst over
    /// the phases `s`. A sample is unseen iff `b > max(−from/s, to/(1−s))` (both
    /// captures outside its interval), so the fraction never falls as `b` grows.
    /// A sample out of both captures' frusta counts as unseen (the truth leaves
    /// it out of both counts: only at spacings beyond the footprint, which the
    /// coverage bound excludes). In `[0, 1]`; 0 for a non-positive or NaN `b`.
    pub fn unseen_at(&self, spacing_m: f64) -> f64 {
        if self.samples == 0 || spacing_m.is_nan() || spacing_m <= 0.0 {
            return 0.0;
        }
        // `β ≥ L` at every phase: only shorter intervals can be unseen.
        let cand: Vec<(f64, f64)> = self
            .occluded
            .iter()
            .map(|&(a, b)| (a as f64, b as f64))
            .filter(|(a, b)| b - a < spacing_m)
            .collect();
        let worst = self
            .phases()
            .map(|s| {
                let k = Phase::new(s);
                cand.iter()
                    .map(|&(a, b)| (k.onset_m(a, b) < spacing_m) as usize)
                    .sum::<usize>()
            })
            .max()
            .unwrap_or(0);
        worst as f64 / self.samples as f64
    }
}

/// One phase `s` of the in-between view, as the reciprocals the onsets need.
#[derive(Debug, Clone, Copy)]
struct Phase {
    inv_s: f64,
    inv_rest: f64,
}

impl Phase {
    fn new(s: f64) -> Phase {
        Phase {
            inv_s: 1.0 / s,
            inv_rest: 1.0 / (1.0 - s),
        }
    }

    /// The spacing beyond which captures at `−s·b` and `(1−s)·b` both miss
    /// `[from, to]`: `max(−from/s, to/(1−s))`.
    #[inline]
    fn onset_m(self, from_m: f64, to_m: f64) -> f64 {
        (-from_m * self.inv_s).max(to_m * self.inv_rest)
    }
}

fn sanitize_fraction(u: f64) -> f64 {
    if u.is_nan() {
        0.0
    } else {
        u.clamp(0.0, 1.0)
    }
}

/// The largest spacing with at most `k_max` unseen samples at every phase: per
/// phase the `(k_max+1)`-th smallest onset, the least of them over phases. The
/// middle phase goes first, and later phases look only at samples that can
/// beat the best so far (`onset ≥ L`).
///
/// `guess` (e.g. the last frame's answer) changes the cost, never the answer:
/// when more than `k_max` onsets of the middle phase lie below it, that phase's
/// order statistic is below it too, and is selected among those alone.
fn unseen_spacing(
    records: &[(f32, f32)],
    k_max: usize,
    phases: usize,
    guess: Option<f64>,
) -> Option<f64> {
    if records.len() <= k_max {
        return None;
    }
    let p = phases.max(1);
    let mid = p.div_ceil(2);
    let mut order: Vec<usize> = vec![mid];
    for d in 1..=p {
        if mid + d <= p {
            order.push(mid + d);
        }
        if mid > d {
            order.push(mid - d);
        }
    }
    let mut best = f64::INFINITY;
    if let Some(g) = guess.filter(|g| *g > 0.0 && g.is_finite()) {
        let k = Phase::new(mid as f64 / (p + 1) as f64);
        let below = records
            .iter()
            .map(|&(a, b)| (k.onset_m(a as f64, b as f64) < g) as usize)
            .sum::<usize>();
        if below > k_max {
            best = g;
        }
    }
    let mut buf: Vec<f64> = Vec::new();
    // The records that can still count: an interval of length `L` has
    // `onset ≥ L` at every phase, so once a phase has set `best`, those with
    // `L ≥ best` never count again. The relative 1e-9 covers the rounding of
    // `L` and of the onsets (a few 1e-16), so the counts are the same.
    let mut live: Vec<(f32, f32)> = Vec::new();
    let mut filtered = false;
    for i in order {
        let k = Phase::new(i as f64 / (p + 1) as f64);
        let onset = |&(a, b): &(f32, f32)| k.onset_m(a as f64, b as f64);
        let set: &[(f32, f32)] = if filtered { &live } else { records };
        // Counted first (branch-free): most phases do not beat the best.
        let n = set
            .iter()
            .map(|r| (onset(r) < best) as usize)
            .sum::<usize>();
        if n > k_max {
            buf.clear();
            buf.extend(set.iter().map(onset).filter(|&o| o < best));
            let (_, v, _) = buf.select_nth_unstable_by(k_max, f64::total_cmp);
            best = best.min(*v);
            let keep = best * (1.0 + 1e-9);
            // A NaN length stays, as the count would see its record.
            let short = |&(a, b): &(f32, f32)| {
                let l = b as f64 - a as f64;
                l < keep || l.is_nan()
            };
            if filtered {
                live.retain(short);
            } else if best.is_finite() {
                live = records.iter().copied().filter(short).collect();
                filtered = true;
            }
        }
    }
    best.is_finite().then_some(best)
}

/// The visibility term over every line of `grid` (the estimator's decimated
/// inverse-depth grid: decimation is its step, along and across track).
///
/// # Model
/// A line of the depth frame is a 2-D profile in the flight plane: a sample at
/// along-track image coordinate `t = v/f` with depth `d` (along the optical
/// axis) is the point `x = d·(sin φ + t·cos φ)` ahead of the camera and
/// `h = d·(cos φ − t·sin φ)` below it (camera at `x = 0`, altitude 0, pitch `φ`;
/// eq. 5). The cameras of the survey move along `h = 0` with the same pitch.
///
/// The sweep works in the projective coordinates `X = x/h`, `Y = 1/h` (for
/// `h > 0`; the samples above the camera's altitude are mirrored, `h → −h`,
/// which keeps every segment to the camera line). Lines map to lines and the
/// camera line to infinity: the camera at `c` becomes the direction `(c, 1)`,
/// and `X` is `tan` of the ray's angle from nadir, so the samples of a line are
/// already sorted by `X` in pixel order. A sample `P` is then hidden from the
/// camera at `c > 0` exactly when some later sample `Q` lies above the ray from
/// `P` with slope `1/c`: the end of its interval ahead is
/// `min over Q of (X_q − X_p)/(Y_q − Y_p)`, the tangent from `P` to the upper
/// convex hull of the samples after it ("the highest slope so far"), kept on a
/// stack and popped in amortised O(1) (with an occluder margin, the tangent from
/// the lifted point is found by walking a few vertices, then bisecting: O(n)
/// in practice, O(n log n) at worst). Behind (`c < 0`) is the same sweep on
/// the mirrored line.
///
/// Approximations, all documented where they act:
/// - **The frame's surface stands for the scene** (a depth mesh): in front of each
///   sample (towards the current camera) is empty, behind it solid; consecutive
///   valid samples are joined. Exact for a height field seen from above (box
///   worlds), where the first occluder of any visible point is itself visible in
///   the frame; under overhangs (tree crowns) it hides too much.
/// - **What is not in the frame cannot occlude**: occluders beyond the image ends,
///   in invalid pixels (skipped: the profile continues across them, the sweep
///   only sees valid samples) or between decimated samples are missed. The
///   profile is sampled at pixel resolution: on a height field the sampled
///   occluders lie on the true surface, so an interval is never shorter than the
///   truth's and longer by at most the camera travel that moves the tangent from
///   the true occluding corner to the sample beside it.
/// - **Sky** (`w = 0`) is neither a surface point nor an occluder.
/// - **2-D**: each line is treated as lying in the vertical plane of the track
///   (exact for every line of a nadir camera, whose lines are epipolar planes
///   through the flight line, and for the centre line at any pitch).
/// - **Frustum along track only**: a camera at `c` sees a point only inside its
///   along-track field of view (image edges at `t = −c_x/f` and `(W − c_x)/f`),
///   as the truth's views per point; the across-track frustum is ignored.
/// - **Occluder margin**: `Q` counts as an occluder of `P` only above `P` moved
///   towards the current camera by the relative `occluder_margin_rel` of its
///   distance (sensor noise and depth quantisation must not make flat ground
///   occlude itself).
///
/// The unseen fraction takes this frame as the in-between view, with captures at
/// `−s·b` and `(1 − s)·b`; see [`Visibility::unseen_at`].
pub fn visibility(
    grid: &InvGrid,
    geom: &TrackGeometry,
    pitch_rad: f64,
    params: &VisibilityParams,
) -> Visibility {
    visibility_on(grid, geom, pitch_rad, params, None)
}

/// Threads the caller lends the sweep (the core names none: threads belong at
/// the edges, STYLE.md). Lines are independent, so the sweep hands its runs of
/// lines to [`SweepWorkers::each`] and merges them in line order: the result
/// has the same bits whoever runs them.
pub trait SweepWorkers: Send + Sync + std::fmt::Debug {
    /// How many can run at once (the sweep makes a few runs per thread).
    fn threads(&self) -> usize;
    /// Calls `job` on every run, in any order, possibly at once. A run left
    /// out is swept after it returns, on the calling thread; one swept again
    /// is not changed.
    fn each(&self, runs: &mut [LineRun], job: &(dyn Fn(&mut LineRun) + Sync));
}

/// One run of consecutive lines of the sweep and what it found there.
#[derive(Debug, Clone)]
pub struct LineRun {
    lines: std::ops::Range<usize>,
    /// Of `lines`, those `a` with `a % stride == phase` (stride 1: all).
    stride: usize,
    phase: usize,
    done: bool,
    /// Whether the occluded samples' intervals are recorded (the watch keeps
    /// only counts and minima).
    records: bool,
    scratch: LineScratch,
    found: Swept,
}

/// What the sweep found on a set of lines: what [`Visibility`] is made of.
#[derive(Debug, Clone)]
struct Swept {
    surface_lines: u64,
    samples: u64,
    occluded_samples: u64,
    occluded_lines: u64,
    /// Shortest interval of any sample, of an occluded one, in the views band.
    min_all: f64,
    min_occ: f64,
    /// The line of `min_all` (`usize::MAX`: none).
    min_line: usize,
    occluded: Vec<(f32, f32)>,
}

impl Default for Swept {
    fn default() -> Self {
        Swept {
            surface_lines: 0,
            samples: 0,
            occluded_samples: 0,
            occluded_lines: 0,
            min_all: f64::INFINITY,
            min_occ: f64::INFINITY,
            min_line: usize::MAX,
            occluded: Vec::new(),
        }
    }
}

/// The shorter of two shortest intervals, each with its line (the first on a
/// tie): how the line of the shortest interval is kept wherever minima meet.
fn shorter(a: (f64, usize), b: (f64, usize)) -> (f64, usize) {
    if b.0 < a.0 {
        b
    } else {
        a
    }
}

impl Swept {
    /// The shortest interval of any sample in the views band, and its line.
    fn shortest(&self) -> (f64, usize) {
        (self.min_all, self.min_line)
    }

    /// Adds `other`'s lines (disjoint from this one's).
    fn add(&mut self, other: &mut Swept) {
        self.surface_lines += other.surface_lines;
        self.samples += other.samples;
        self.occluded_samples += other.occluded_samples;
        self.occluded_lines += other.occluded_lines;
        (self.min_all, self.min_line) = shorter(self.shortest(), other.shortest());
        self.min_occ = self.min_occ.min(other.min_occ);
        if self.occluded.is_empty() {
            self.occluded = std::mem::take(&mut other.occluded);
        } else {
            self.occluded.extend_from_slice(&other.occluded);
        }
    }

    /// Whether these lines' shortest interval (of any sample, or of an
    /// occluded one, in the views band) came out shorter than on their sweep
    /// `before` by more than `rel` ([`Interleave::refreshing`]): `Some` of the
    /// smaller ratio now / then (0 where there was none before).
    fn shorter_than(&self, before: &Swept, rel: f64) -> Option<f64> {
        let ratio = |now: f64, then: f64| {
            (now < then * (1.0 - rel)).then(|| if then.is_finite() { now / then } else { 0.0 })
        };
        match (
            ratio(self.min_all, before.min_all),
            ratio(self.min_occ, before.min_occ),
        ) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The counts and minima, without the records.
    fn summary(&self) -> Swept {
        Swept {
            occluded: Vec::new(),
            ..*self
        }
    }

    /// Whether these lines' share of occluded samples came out larger than on
    /// their sweep `before` by more than `rel`.
    fn more_occluded_than(&self, before: &Swept, rel: f64) -> bool {
        // Shares compared as cross products: no division by an empty sweep.
        self.occluded_samples as f64 * before.samples as f64
            > before.occluded_samples as f64 * self.samples as f64 * (1.0 + rel)
    }
}

impl LineRun {
    fn new(lines: std::ops::Range<usize>, stride: usize, phase: usize, records: bool) -> LineRun {
        LineRun {
            lines,
            stride: stride.max(1),
            phase,
            done: false,
            records,
            scratch: LineScratch::default(),
            found: Swept::default(),
        }
    }

    /// Sweeps the run's lines once (again: nothing); `in_band`: the lines that
    /// set the views bound.
    fn sweep(
        &mut self,
        grid: &InvGrid,
        rays: &TrackRays,
        margin_rel: f64,
        in_band: &std::ops::Range<usize>,
    ) {
        if self.done {
            return;
        }
        self.done = true;
        // Counted in locals (a store through `self` beside the pushes would
        // be reloaded every sample), in the same order: the same minima.
        let f = &mut self.found;
        let (mut samples, mut occluded_samples) = (f.samples, f.occluded_samples);
        let (mut min_all, mut min_occ) = (f.min_all, f.min_occ);
        let records = &mut f.occluded;
        let keep = self.records;
        let (stride, phase) = (self.stride, self.phase);
        let mut min_line = f.min_line;
        for a in self.lines.clone().filter(|a| a % stride == phase) {
            let (mut surface, mut occluded) = (false, false);
            let min_before = min_all;
            let counts = in_band.contains(&a);
            sweep_line(
                grid.line(a),
                rays,
                margin_rel,
                &mut self.scratch,
                |_, iv| {
                    surface = true;
                    samples += 1;
                    let l = iv.length_m();
                    if counts {
                        min_all = min_all.min(l);
                    }
                    if iv.occluded() {
                        occluded = true;
                        occluded_samples += 1;
                        if counts {
                            min_occ = min_occ.min(l);
                        }
                        if keep {
                            records.push((iv.from_m as f32, iv.to_m as f32));
                        }
                    }
                },
            );
            f.surface_lines += surface as u64;
            f.occluded_lines += occluded as u64;
            if min_all < min_before {
                min_line = a;
            }
        }
        f.min_line = min_line;
        (f.samples, f.occluded_samples) = (samples, occluded_samples);
        (f.min_all, f.min_occ) = (min_all, min_occ);
    }
}

/// [`visibility`], its lines swept by `workers` (`None`: on the calling thread).
pub fn visibility_on(
    grid: &InvGrid,
    geom: &TrackGeometry,
    pitch_rad: f64,
    params: &VisibilityParams,
    workers: Option<&dyn SweepWorkers>,
) -> Visibility {
    let mut found = FrameSweep::new(grid, geom, pitch_rad, params, workers).lines(1, 0);
    Visibility::from_swept(params, &mut found, None)
}

/// One frame's sweep: its grid, the rays of its samples along track (built
/// once a frame, whichever sets of lines the frame sweeps), and the lines that
/// set the views bound.
struct FrameSweep<'a> {
    grid: &'a InvGrid,
    /// `None`: nothing to sweep (no samples on a line, or no pitch).
    rays: Option<TrackRays>,
    in_band: std::ops::Range<usize>,
    margin_rel: f64,
    workers: Option<&'a dyn SweepWorkers>,
}

impl<'a> FrameSweep<'a> {
    fn new(
        grid: &'a InvGrid,
        geom: &TrackGeometry,
        pitch_rad: f64,
        params: &VisibilityParams,
        workers: Option<&'a dyn SweepWorkers>,
    ) -> FrameSweep<'a> {
        let rays = (grid.per_line > 0 && pitch_rad.is_finite())
            .then(|| TrackRays::new(geom, &grid.along_idx, pitch_rad));
        let band = if params.views_band.is_finite() {
            params.views_band.clamp(0.0, 1.0)
        } else {
            1.0
        };
        let skip = ((grid.lines as f64 * (1.0 - band) * 0.5).floor() as usize).min(grid.lines / 2);
        FrameSweep {
            grid,
            rays,
            in_band: skip..grid.lines - skip,
            margin_rel: params.occluder_margin_rel,
            workers,
        }
    }

    /// The lines `a ≡ phase (mod stride)`, swept by the frame's workers.
    fn lines(&self, stride: usize, phase: usize) -> Swept {
        self.run(0..self.grid.lines, stride, phase, self.workers, true)
    }

    /// The lines `a ≡ phase (mod stride)` in `within` alone, on the calling
    /// thread (a few lines: not worth a thread), their counts and minima
    /// without the occluded samples' records ([`Interleave::watching`]).
    fn beside(&self, within: std::ops::Range<usize>, stride: usize, phase: usize) -> Swept {
        self.run(within, stride, phase, None, false)
    }

    fn run(
        &self,
        within: std::ops::Range<usize>,
        stride: usize,
        phase: usize,
        workers: Option<&dyn SweepWorkers>,
        records: bool,
    ) -> Swept {
        let mut found = Swept::default();
        let grid = self.grid;
        let within = within.start.min(grid.lines)..within.end.min(grid.lines);
        let Some(rays) = self.rays.as_ref().filter(|_| !within.is_empty()) else {
            return found;
        };
        let (margin, in_band) = (self.margin_rel, &self.in_band);
        let threads = workers.map_or(1, |w| w.threads().max(1));
        let (lo, len) = (within.start, within.len());
        let mut runs: Vec<LineRun> = if threads == 1 {
            vec![LineRun::new(within, stride, phase, records)]
        } else {
            // A few runs per thread, so that a thread whose lines hold the
            // occluders does not keep the others waiting.
            let n = (4 * threads).min(len);
            (0..n)
                .map(|i| {
                    let lines = lo + i * len / n..lo + (i + 1) * len / n;
                    LineRun::new(lines, stride, phase, records)
                })
                .collect()
        };
        if let Some(w) = workers.filter(|_| runs.len() > 1) {
            w.each(&mut runs, &|r| r.sweep(grid, rays, margin, in_band));
        }
        // Here what no worker took (none lent, or one that could not start).
        for r in &mut runs {
            r.sweep(grid, rays, margin, in_band);
        }
        // In line order: the occluded samples in the order one thread gives them.
        for r in &mut runs {
            found.add(&mut r.found);
        }
        found
    }
}

impl Visibility {
    /// The term from what the sweep found (its records are taken); `guess`:
    /// [`unseen_spacing`]'s.
    fn from_swept(params: &VisibilityParams, found: &mut Swept, guess: Option<f64>) -> Visibility {
        let mut v = Visibility::empty(params);
        v.lines = found.surface_lines;
        v.samples = found.samples;
        v.occluded_samples = found.occluded_samples;
        v.occluded_lines = found.occluded_lines;
        v.occluded = std::mem::take(&mut found.occluded);
        let (min_all, min_occ) = (found.min_all, found.min_occ);
        let k = v.views_per_point_min as f64;
        v.interval_min_m = min_all.is_finite().then_some(min_all);
        v.occluded_interval_min_m = min_occ.is_finite().then_some(min_occ);
        v.spacing_views_m = v.interval_min_m.map(|l| l / k);
        v.spacing_views_occluded_m = v.occluded_interval_min_m.map(|l| l / k);
        if v.samples > 0 && v.unseen_fraction_max < 1.0 {
            // At most `k_max` unseen samples keeps the fraction within the target.
            let k_max = (v.unseen_fraction_max * v.samples as f64).floor() as usize;
            v.spacing_unseen_m = unseen_spacing(&v.occluded, k_max, v.phases, guess);
        }
        v
    }
}

/// The visibility sweep spread over the frames of a flight: each frame sweeps
/// every `stride`-th line across track, the next frame the next set, and the
/// term is taken over the newest sweep of every line. A line's sweep is then at
/// most `stride − 1` frames old (at 30 fps and 10 m/s, 0.33 m of travel a
/// frame, against a footprint of tens of metres), and the frame costs
/// `1/stride` of the whole sweep at full resolution along and across track:
/// unlike a coarser grid, no line and no sample is left out for good, so the
/// narrowest gap is found within `stride` frames (docs/error-vs-runtime.md).
/// The views bound also holds the shortest interval any of the last
/// `2 × stride` frames found (see `Interleave::remember`); the unseen fraction
/// is the newest sweeps' alone.
///
/// A grid of another shape (frame size, decimation) sweeps every line and
/// starts the turn again; so does the first frame, and so does one after
/// [`Interleave::reset`] (the estimator's on a new track axis).
///
/// [`Interleave::refreshing`] also sweeps every line on a frame whose own lines
/// came out tighter than on their own last turn (see [`Interleave::refreshing`]),
/// and [`Interleave::watching`] the lines beside the shortest interval on every
/// frame.
#[derive(Debug, Clone, Default)]
pub struct Interleave {
    /// `(lines, per_line, stride)` the parts were swept with.
    key: Option<(usize, usize, usize)>,
    /// The newest sweep of each residue class of lines.
    parts: Vec<Swept>,
    /// Each class's sweep on its own turn, without its records.
    own: Vec<Swept>,
    /// The shortest intervals `(min_all, min_occ)` each of the last
    /// `2 × stride` frames swept, and the line of `min_all`, by frame modulo
    /// its length: the views bound holds them (see [`visibility_interleaved`]).
    recent: Vec<(f64, f64, usize)>,
    /// Frames since the parts were started.
    frames: usize,
    /// The class the next frame sweeps.
    next: usize,
    /// Whether the last frame swept every line (the first, or a new shape).
    full: bool,
    /// The last frame's unseen spacing: where the next one's search starts.
    unseen_m: Option<f64>,
    /// [`Interleave::refreshing`]'s margin (`None`: the turn alone).
    refresh_rel: Option<f64>,
    /// Frames that swept every line because their own lines had tightened.
    refreshed: u64,
    /// Whether every frame also sweeps the lines beside the shortest interval
    /// held ([`Interleave::watching`]).
    watch: bool,
}

/// The estimator's margin for [`Interleave::refreshing`]: a class of lines 5 %
/// tighter than `stride` frames before sweeps every line. Not tuned: it is the
/// error by which `examples/visibility_interleave.rs` counts a frame's spacing
/// too long, fixed before the rule was measured (docs/error-vs-runtime.md).
pub const INTERLEAVE_REFRESH_REL: f64 = 0.05;

impl Interleave {
    /// Also sweeps every line on a frame whose class of lines, against that
    /// class's sweep on its own last turn (`stride` frames before, whatever
    /// frame swept every line in between), has a shortest interval (of any
    /// sample, or of an occluded one, in the views band) shorter by more than
    /// `rel`, or a share of occluded samples larger by more than `rel`. The
    /// other classes are older still, and where the scene tightens (an
    /// occluder entering the view) their kept sweeps would lengthen the spacing
    /// for up to `stride − 1` frames; where it loosens, kept sweeps only
    /// shorten it. A still scene costs what the turn costs. (Against the last
    /// sweep instead, which a frame sweeping every line replaces, a scene that
    /// tightens a little on each of a few frames never crosses `rel`: an
    /// occluder entering `alfd sim`'s flight at 400 m was seen three frames
    /// late.)
    ///
    /// A shorter interval alone sweeps every line only where it can decide
    /// the frame's spacing: the views spacing predicted with every other
    /// class shortened by the same ratio (and the intervals the last frames
    /// hold) must come within `rel` of what the frame's other terms allow
    /// (`others_m` of [`visibility_interleaved`]), widened by the spread of
    /// the shortest intervals the last `2 × stride` frames found (one class
    /// can be that much shorter than another: a narrow gap's floor, see
    /// [`Interleave::remember`]). Approaching a tower, the interval shortens
    /// frame after frame far above the parallax bound; sweeping every line
    /// there changed no capture of `alfd sim --sweep flight`
    /// (docs/error-vs-runtime.md).
    pub fn refreshing(rel: f64) -> Interleave {
        Interleave {
            refresh_rel: Some(if rel.is_finite() { rel.max(0.0) } else { 0.0 }),
            ..Interleave::default()
        }
    }

    /// Also sweeps, on every frame, the `stride` lines either side of the line
    /// holding the shortest interval the term holds (of every class but the
    /// frame's own: one or two lines of each). Their shortest intervals join
    /// the views bound as the frame's own do; their counts and records are not
    /// kept.
    pub fn watching(mut self) -> Interleave {
        self.watch = true;
        self
    }

    /// The line of the shortest interval of the newest sweeps and the
    /// intervals held.
    fn hot_line(&self) -> Option<usize> {
        let held = self.recent.iter().map(|&(all, _, line)| (all, line));
        let best = (self.parts.iter().map(Swept::shortest).chain(held))
            .fold((f64::INFINITY, usize::MAX), shorter);
        (best.1 != usize::MAX).then_some(best.1)
    }

    /// Forgets every part: the next frame sweeps every line.
    pub fn reset(&mut self) {
        self.key = None;
        self.parts.clear();
        self.own.clear();
        self.recent.clear();
        self.frames = 0;
        self.next = 0;
        self.full = false;
        self.unseen_m = None;
    }

    /// Records the shortest intervals of the classes `swept` on this frame. The
    /// views bound is the shortest interval found on the last `2 × stride`
    /// frames, not only on each line's newest sweep: a point's interval is the
    /// scene's and the track's, not the frame's, but a narrow gap's bottom
    /// falls between a line's samples at some sub-pixel phases of the ground
    /// under the camera, and that phase moves from frame to frame (1.55 pixels
    /// a frame at 100 m and 10 m/s over 640 columns at 69°). Each line's
    /// newest sweep is one phase; the window holds at least two sweeps of
    /// every line (docs/error-vs-runtime.md).
    fn remember(&mut self, swept: std::ops::Range<usize>, local: Option<&Swept>) {
        let n = self.recent.len();
        if n == 0 {
            return;
        }
        let (mut all, mut occ) = ((f64::INFINITY, usize::MAX), f64::INFINITY);
        for part in self.parts[swept].iter().chain(local) {
            all = shorter(all, part.shortest());
            occ = occ.min(part.min_occ);
        }
        self.recent[self.frames % n] = (all.0, occ, all.1);
        self.frames += 1;
    }

    /// [`Interleave::refreshing`]'s test of the class `phase` swept `fresh`
    /// (before `fresh` replaces it).
    fn tightened(
        &self,
        fresh: &Swept,
        phase: usize,
        rel: f64,
        params: &VisibilityParams,
        others_m: Option<f64>,
    ) -> bool {
        let before = &self.own[phase];
        if fresh.more_occluded_than(before, rel) {
            return true;
        }
        let Some(ratio) = fresh.shorter_than(before, rel) else {
            return false;
        };
        let Some(others_m) = others_m.filter(|o| o.is_finite()) else {
            return true;
        };
        // Every other class shortened as this one did, and what the last
        // frames hold: the views spacing that predicts. Where it stays well
        // above what the other terms allow, sweeping the other classes now
        // would not change the frame's spacing; their turn comes within
        // `stride` frames.
        let mut shortest = fresh.min_all;
        for (c, part) in self.parts.iter().enumerate() {
            if c != phase {
                shortest = shortest.min(part.min_all * ratio);
            }
        }
        let mut longest = fresh.min_all;
        for &(all, _, _) in &self.recent {
            shortest = shortest.min(all);
            if all.is_finite() {
                longest = longest.max(all);
            }
        }
        // How much the classes' shortest intervals have differed: by this much
        // a class not swept can be shorter than the prediction.
        let spread = if shortest > 0.0 {
            (longest / shortest).max(1.0)
        } else {
            f64::INFINITY
        };
        let k = params.views_per_point_min.max(1) as f64;
        shortest / k <= others_m * (1.0 + rel) * spread
    }

    /// Frames so far that swept every line because their lines had tightened.
    pub fn refreshed_frames(&self) -> u64 {
        self.refreshed
    }

    /// Whether the last frame swept every line itself.
    pub fn swept_every_line(&self) -> bool {
        self.full
    }
}

/// [`visibility_on`] of a frame of a flight, sweeping one in `stride` lines and
/// taking the others from the last frames (`state`; see [`Interleave`]).
/// `stride` 1 (or 0) is [`visibility_on`] exactly. `others_m`: the largest
/// spacing the frame's other terms allow (`None`: not known), against which
/// [`Interleave::refreshing`] judges whether a shorter interval can matter.
#[allow(clippy::too_many_arguments)]
pub fn visibility_interleaved(
    grid: &InvGrid,
    geom: &TrackGeometry,
    pitch_rad: f64,
    params: &VisibilityParams,
    workers: Option<&dyn SweepWorkers>,
    stride: usize,
    others_m: Option<f64>,
    state: &mut Interleave,
) -> Visibility {
    let stride = stride.max(1).min(grid.lines.max(1));
    if stride == 1 {
        state.reset();
        state.full = true;
        return visibility_on(grid, geom, pitch_rad, params, workers);
    }
    let frame = FrameSweep::new(grid, geom, pitch_rad, params, workers);
    let key = (grid.lines, grid.per_line, stride);
    if state.key != Some(key) {
        state.parts = (0..stride)
            .map(|phase| frame.lines(stride, phase))
            .collect();
        state.key = Some(key);
        state.own = state.parts.iter().map(Swept::summary).collect();
        state.next = 0;
        state.full = true;
        state.recent = vec![(f64::INFINITY, f64::INFINITY, usize::MAX); 2 * stride];
        state.frames = 0;
        state.remember(0..stride, None);
    } else {
        let phase = state.next;
        let fresh = frame.lines(stride, phase);
        state.full = state
            .refresh_rel
            .is_some_and(|rel| state.tightened(&fresh, phase, rel, params, others_m));
        state.own[phase] = fresh.summary();
        state.parts[phase] = fresh;
        if state.full {
            state.refreshed += 1;
            for other in (0..stride).filter(|&c| c != phase) {
                state.parts[other] = frame.lines(stride, other);
            }
            state.remember(0..stride, None);
        } else {
            // The lines beside the shortest interval held, of every other
            // class: where a narrow gap's floor shows at some sub-pixel
            // phases only, a one-frame dip is likeliest there.
            let local = state.watch.then_some(stride).and_then(|r| {
                let hot = state.hot_line()?;
                let within = hot.saturating_sub(r)..(hot + r + 1).min(grid.lines);
                let mut m = Swept::default();
                for c in (0..stride).filter(|&c| c != phase) {
                    m.add(&mut frame.beside(within.clone(), stride, c));
                }
                Some(m)
            });
            state.remember(phase..phase + 1, local.as_ref());
        }
        state.next = (phase + 1) % stride;
    }
    let mut found = Swept::default();
    for part in &state.parts {
        // The parts are kept for the frames to come: their records copied.
        let mut copy = Swept {
            occluded: part.occluded.clone(),
            ..*part
        };
        found.add(&mut copy);
    }
    // Every frame's sweep also holds for the next `2 × stride − 1` frames: see
    // `Interleave::remember`.
    for &(all, occ, _) in &state.recent {
        found.min_all = found.min_all.min(all);
        found.min_occ = found.min_occ.min(occ);
    }
    // Most frames' answer is within a factor of the last one's.
    let v = Visibility::from_swept(params, &mut found, state.unseen_m.map(|u| u * 1.5));
    state.unseen_m = v.spacing_unseen_m;
    v
}

/// [`visibility`] of a depth image sampled every `step` pixels (every valid
/// depth, no range limits): the one-shot form for tests and the command line.
pub fn visibility_of_image(
    image: &DepthImage,
    intr: &Intrinsics,
    axis: TrackAxis,
    step: usize,
    pitch_rad: f64,
    params: &VisibilityParams,
) -> Visibility {
    let mut grid = InvGrid::default();
    fill_grid(image, axis, step, &DepthRange::default(), &mut grid);
    visibility(&grid, &intr.track(axis), pitch_rad, params)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sweep on `(X, Y)` pairs, either way.
    fn sweep(pts: &[(f64, f64)], behind: bool, margin: f64, out: &mut Vec<f64>) {
        let (xs, ys): (Vec<f64>, Vec<f64>) = pts.iter().copied().unzip();
        let mut hull = Hull::default();
        out.clear();
        out.resize(xs.len(), f64::NAN);
        if behind {
            super::sweep::<true>(&xs, &ys, margin, &mut hull, |i, v| out[i] = v);
        } else {
            super::sweep::<false>(&xs, &ys, margin, &mut hull, |i, v| out[i] = v);
        }
    }

    /// The sweep as it was before the hull left out what never occludes: every
    /// point pushed on a stack of pairs.
    fn plain_sweep(
        pts: &[(f64, f64)],
        behind: bool,
        margin: f64,
        stack: &mut Vec<(f64, f64)>,
        out: &mut Vec<f64>,
    ) {
        let n = pts.len();
        out.clear();
        out.resize(n, f64::INFINITY);
        stack.clear();
        let sign = if behind { -1.0 } else { 1.0 };
        // `slope(P, a) ≤ slope(P, b)` for `a`, `b` beyond `P`, without dividing.
        #[inline]
        fn not_above(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> bool {
            (a.1 - p.1) * (b.0 - p.0) <= (b.1 - p.1) * (a.0 - p.0)
        }
        // The highest `Y` of the points beyond `p` (all swept so far).
        let mut y_beyond = f64::NEG_INFINITY;
        // The top of the stack, also kept here: reading back the point pushed one
        // iteration before (two 8-byte stores, one 16-byte load) stalls on store
        // forwarding, which was the sweep's largest cost.
        let mut last = (0.0, 0.0);
        for k in 0..n {
            let i = if behind { k } else { n - 1 - k };
            let p = (sign * pts[i].0, pts[i].1);
            // The hull of the points beyond `p`, seen from `p`: what lies on or
            // under the chord from `p` to the next vertex is no one's tangent.
            while stack.len() >= 2 {
                let b = stack[stack.len() - 2];
                if not_above(p, last, b) {
                    stack.pop();
                    last = b;
                } else {
                    break;
                }
            }
            let pl = (p.0, p.1 * (1.0 + margin));
            if pl.1 >= y_beyond {
                // Nothing beyond rises above the lifted point, so no tangent has
                // `dy > 0` and this side stays open (open ground, roofs): the
                // walk below would find the same.
                stack.push(p);
                last = p;
                y_beyond = y_beyond.max(p.1);
                continue;
            }
            let tangent = if margin > 0.0 && stack.len() >= 2 {
                // From the lifted point the tangent lies at or beyond the top:
                // slopes along the chain rise, then fall. A small lift moves it a
                // vertex or two: walk a few, then bisect the rest.
                // Chain order: c = 0 is the top (nearest), stack index len−1−c.
                let top = stack.len() - 1;
                let at = |c: usize| if c == 0 { last } else { stack[top - c] };
                let mut lo = 0usize;
                while lo < top.min(4) && !not_above(pl, at(lo + 1), at(lo)) {
                    lo += 1;
                }
                if lo == 4 && lo < top {
                    let mut hi = top;
                    while lo < hi {
                        let mid = (lo + hi) / 2;
                        if not_above(pl, at(mid + 1), at(mid)) {
                            hi = mid;
                        } else {
                            lo = mid + 1;
                        }
                    }
                }
                Some(at(lo))
            } else {
                (!stack.is_empty()).then_some(last)
            };
            if let Some(q) = tangent {
                let dy = q.1 - pl.1;
                if dy > 0.0 {
                    out[i] = (q.0 - p.0).max(0.0) / dy;
                }
            }
            stack.push(p);
            last = p;
            y_beyond = y_beyond.max(p.1);
        }
    }

    #[test]
    fn the_hull_without_the_floor_points_gives_the_plain_sweeps_bits() {
        // Profiles as depth lines give them: open ground with noise under and
        // over the margin, plateaus (quantised depth), steps up and down,
        // posts, and a ramp; both ways, with and without a margin.
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for case in 0..400 {
            let n = 1 + (next() * 300.0) as usize;
            let noise = [0.0, 1e-5, 1e-3, 0.05][case % 4];
            let quantum = [0.0, 1e-3][case / 4 % 2];
            let mut x = -2.0 + next();
            let mut level = 1.0;
            let (mut xs, mut ys) = (Vec::new(), Vec::new());
            for _ in 0..n {
                x += 0.001 + next() * 0.05;
                let u = next();
                if u < 0.03 {
                    level = 1.0 + next() * 1.5;
                } else if u < 0.06 {
                    level = 1.0;
                }
                let mut y = level + (next() - 0.5) * noise + (case % 3) as f64 * 0.01 * x;
                if quantum > 0.0 {
                    y = (y / quantum).round() * quantum;
                }
                xs.push(x);
                ys.push(y.max(1e-3));
            }
            let pts: Vec<(f64, f64)> = xs.iter().copied().zip(ys.iter().copied()).collect();
            for margin in [0.0, 1e-4, 1e-3, 0.2] {
                for behind in [false, true] {
                    let (mut want, mut got) = (Vec::new(), Vec::new());
                    plain_sweep(&pts, behind, margin, &mut Vec::new(), &mut want);
                    sweep(&pts, behind, margin, &mut got);
                    let bits = |v: &[f64]| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "case {case} margin {margin} behind {behind}"
                    );
                }
            }
        }
    }

    #[test]
    fn sweep_finds_the_highest_slope_ahead() {
        // Flat, then a step up: the first point is hidden beyond the tangent
        // over the step's top, (3 − 0)/(2 − 1) = 3.
        let pts = [(0.0, 1.0), (1.0, 1.0), (3.0, 2.0), (4.0, 2.0)];
        let mut out = Vec::new();
        sweep(&pts, false, 0.0, &mut out);
        assert_eq!(out[0], 3.0);
        assert_eq!(out[1], 2.0);
        assert!(out[2].is_infinite() && out[3].is_infinite());
        // Behind: nothing before a point rises above it.
        sweep(&pts, true, 0.0, &mut out);
        assert!(out.iter().all(|c| c.is_infinite()));
    }

    /// The sweep on `(x, y)` against the brute-force tangent of every point, each margin
    /// and direction.
    fn assert_sweep_is_brute_force(x: &[f64], y: &[f64], margins: &[f64]) {
        let pts: Vec<(f64, f64)> = x.iter().copied().zip(y.iter().copied()).collect();
        for &margin in margins {
            for behind in [false, true] {
                let mut out = Vec::new();
                sweep(&pts, behind, margin, &mut out);
                for i in 0..x.len() {
                    let yl = y[i] * (1.0 + margin);
                    let others = if behind { 0..i } else { i + 1..x.len() };
                    let brute = others
                        .filter(|&q| y[q] > yl)
                        .map(|q| (x[q] - x[i]).abs() / (y[q] - yl))
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        (out[i] - brute).abs() <= 1e-12 * brute.abs().max(1.0)
                            || (out[i].is_infinite() && brute.is_infinite()),
                        "margin {margin} behind {behind} point {i}: sweep {} brute {brute}",
                        out[i]
                    );
                }
            }
        }
    }

    #[test]
    fn lifted_tangent_matches_brute_force() {
        let x: Vec<f64> = (0..40).map(|i| i as f64 * 0.37).collect();
        let y: Vec<f64> = (0..40)
            .map(|i| 1.0 + ((i * 7919) % 13) as f64 * 0.1)
            .collect();
        assert_sweep_is_brute_force(&x, &y, &[0.0, 0.01, 0.2]);
    }

    #[test]
    fn open_ground_exit_matches_brute_force() {
        // Flat ground with depth noise under the margin, a block and a post:
        // most points take the early exit (nothing beyond rises above them).
        let x: Vec<f64> = (0..60).map(|i| i as f64 * 0.21 - 3.0).collect();
        let y: Vec<f64> = (0..60)
            .map(|i| match i {
                12..=15 => 1.6,
                41 => 1.3,
                _ => 1.0 + ((i * 7919) % 7) as f64 * 1e-4,
            })
            .collect();
        assert_sweep_is_brute_force(&x, &y, &[0.0, 1e-4, 1e-3, 0.5]);
    }

    #[test]
    fn unseen_spacing_equals_every_phase_sorted() {
        // Intervals of all lengths, some open at one end (the frustum never
        // loses the point): the pruned search against a sort of every phase.
        let mut s = 99u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        for n in [1usize, 2, 7, 50, 400] {
            let recs: Vec<(f32, f32)> = (0..n)
                .map(|i| {
                    let (a, b) = (-next() * 30.0, next() * 30.0);
                    match i % 11 {
                        3 => (f32::NEG_INFINITY, b),
                        7 => (a, f32::INFINITY),
                        _ => (a, b),
                    }
                })
                .collect();
            for phases in [1usize, 2, 15] {
                for k_max in [0usize, 1, 3, n / 2, n] {
                    let p = phases;
                    let want = (1..=p)
                        .filter_map(|i| {
                            let k = Phase::new(i as f64 / (p + 1) as f64);
                            let mut o: Vec<f64> = recs
                                .iter()
                                .map(|&(a, b)| k.onset_m(a as f64, b as f64))
                                .collect();
                            o.sort_by(f64::total_cmp);
                            o.get(k_max).copied()
                        })
                        .fold(f64::INFINITY, f64::min);
                    let want = want.is_finite().then_some(want);
                    // Whatever the guess: below, at, just above, far above the
                    // answer, none, or nonsense.
                    let w = want.unwrap_or(1.0);
                    for guess in [
                        None,
                        Some(w * 0.5),
                        Some(w),
                        Some(w * (1.0 + 1e-12)),
                        Some(w * 1.5),
                        Some(1e9),
                        Some(0.0),
                        Some(f64::NAN),
                    ] {
                        assert_eq!(
                            unseen_spacing(&recs, k_max, phases, guess),
                            want,
                            "n {n} phases {phases} k_max {k_max} guess {guess:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn unseen_spacing_is_the_order_statistic() {
        // Symmetric intervals of length 2, 4, 6: at the middle phase the onset
        // is the length.
        let recs = [(-1.0f32, 1.0f32), (-2.0, 2.0), (-3.0, 3.0)];
        assert_eq!(unseen_spacing(&recs, 0, 1, None), Some(2.0));
        assert_eq!(unseen_spacing(&recs, 1, 1, None), Some(4.0));
        assert_eq!(unseen_spacing(&recs, 3, 1, None), None);
    }
}
