//! Inverse depth on a decimated, track-major sample grid, and exact order
//! statistics of it in O(n): for Z16 frames from a count of the raw values made
//! in the same pass (inverse depth falls monotonically with the Z16 value), else
//! by a three-level radix histogram of the floats (no sort).
//!
//! Invariant: a grid value is `INVALID` or `FAR` (negative), `SKY` (0.0) or a
//! finite positive inverse depth in 1/m. Non-negative `f32` bit patterns order like
//! their values, which is what makes the radix selection exact.

use super::depth::{DepthData, DepthImage, TrackAxis};

/// Marker for a masked pixel (NaN, not positive, nearer than the range).
pub const INVALID: f32 = -1.0;
/// Marker for a pixel beyond the range: no return (Z16 0), saturation
/// (`u16::MAX`) or a depth past the range's maximum. Below the horizon that is
/// ground too far for the sensor (or a surface that returns nothing), not sky:
/// the estimate counts it (`Estimate::far_below_samples`).
pub const FAR: f32 = -2.0;
/// Inverse depth of the sky (`d = +inf`).
pub const SKY: f32 = 0.0;

/// Which depths count as valid, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthRange {
    pub min_m: f64,
    pub max_m: f64,
}

impl Default for DepthRange {
    fn default() -> Self {
        DepthRange {
            min_m: 0.0,
            max_m: f64::INFINITY,
        }
    }
}

/// Inverse depth sampled every `step` pixels, laid out as lines along track.
#[derive(Debug, Clone, Default)]
pub struct InvGrid {
    pub step: usize,
    /// Number of lines (across track).
    pub lines: usize,
    /// Samples per line (along track).
    pub per_line: usize,
    pub w: Vec<f32>,
    /// Original pixel index along track of each sample.
    pub along_idx: Vec<usize>,
    /// Original pixel index across track of each line.
    pub across_idx: Vec<usize>,
    pub valid: usize,
    pub sky: usize,
    /// Samples that are `FAR`.
    pub far: usize,
    /// Inverse depth of every Z16 value, for the `(scale, range)` in `lut_key`:
    /// one load per pixel instead of a conversion and a division.
    lut: Vec<f32>,
    lut_key: Option<[u64; 3]>,
    /// The Z16 values whose table entry is valid, `lo..=hi`, when every one of
    /// them is a finite positive inverse depth (`None`: no such value, or a
    /// degenerate scale; the count is then not used).
    lut_valid: Option<(usize, usize)>,
    /// Count of each sampled Z16 value, made by [`fill_grid_counted`].
    hist: Vec<u32>,
    /// Whether `hist` counts the current samples.
    counted: bool,
}

impl InvGrid {
    pub fn line(&self, a: usize) -> &[f32] {
        &self.w[a * self.per_line..(a + 1) * self.per_line]
    }
    pub fn samples(&self) -> usize {
        self.w.len()
    }

    /// Exact order statistics (0-based `ranks`, ascending) of the grid's valid
    /// inverse depths, as [`Selector::select2`] gives them on `w`: from the
    /// count of Z16 values when [`fill_grid_counted`] made one (a Z16 frame has
    /// no sky, and the `k`-th smallest inverse depth is the table's entry of
    /// the `k`-th largest valid Z16 value, so the result is the same value),
    /// else by selection over the samples.
    pub fn select2(
        &self,
        selector: &mut Selector,
        include_sky: bool,
        ranks: [u64; 2],
    ) -> Option<[f32; 2]> {
        let (lo, hi) = match (self.counted, self.lut_valid) {
            (true, Some(range)) => range,
            _ => return selector.select2(&self.w, include_sky, ranks),
        };
        let hist: &[u32] = &self.hist[lo..=hi];
        let total = self.valid as u64;
        if ranks.iter().any(|&r| r >= total) {
            return None;
        }
        // Ascending inverse depth is descending Z16: count from whichever end
        // of the histogram is nearer the rank (the percentiles are tails).
        let z_of = |r: u64| {
            if r < total / 2 {
                hi - nth_from_top(hist, r)
            } else {
                lo + nth_from_bottom(hist, total - 1 - r)
            }
        };
        Some(ranks.map(|r| self.lut[z_of(r)]))
    }
}

/// Bins of 64 summed before the bins one by one: the tails of a depth
/// histogram are long runs of empty bins.
const BLOCK: usize = 64;

/// Index of the bin holding the 0-based `rank`-th count from the start.
fn nth_from_bottom(hist: &[u32], mut rank: u64) -> usize {
    let mut start = 0;
    for block in hist.chunks_exact(BLOCK) {
        let c: u64 = block.iter().map(|&c| c as u64).sum();
        if rank < c {
            break;
        }
        rank -= c;
        start += BLOCK;
    }
    for (b, &c) in hist[start..].iter().enumerate() {
        if rank < c as u64 {
            return start + b;
        }
        rank -= c as u64;
    }
    // Callers pass rank < total, so the loop always returns; stay total anyway.
    hist.len().saturating_sub(1)
}

/// Distance from the end of the bin holding the `rank`-th count from the end.
fn nth_from_top(hist: &[u32], mut rank: u64) -> usize {
    let mut end = hist.len();
    for block in hist.rchunks_exact(BLOCK) {
        let c: u64 = block.iter().map(|&c| c as u64).sum();
        if rank < c {
            break;
        }
        rank -= c;
        end -= BLOCK;
    }
    for (b, &c) in hist[..end].iter().rev().enumerate() {
        if rank < c as u64 {
            return hist.len() - end + b;
        }
        rank -= c as u64;
    }
    hist.len().saturating_sub(1)
}

/// Sample indices for a stride `step` over `extent` pixels: the centre of each block.
/// Samples of a `width × height` frame's grid at `step` ([`sample_indices`]
/// both ways).
pub fn grid_samples(width: usize, height: usize, step: usize) -> usize {
    let n = |extent: usize| (extent / step.max(1)).max(1);
    n(width) * n(height)
}

/// The coarsest step, 1 to 256, whose grid of a `width × height` frame keeps
/// at least `min` samples (1 when none does).
pub fn coarsest_step(width: usize, height: usize, min: usize) -> usize {
    (1..=256)
        .rev()
        .find(|&s| grid_samples(width, height, s) >= min)
        .unwrap_or(1)
}

pub fn sample_indices(extent: usize, step: usize) -> Vec<usize> {
    let step = step.max(1);
    if extent < step {
        return vec![extent / 2];
    }
    (0..extent / step).map(|j| j * step + step / 2).collect()
}

#[inline]
fn inv_from_metres(d: f32, range: &DepthRange) -> f32 {
    if d == f32::INFINITY {
        return SKY;
    }
    // NaN fails every comparison and lands here too.
    let d64 = d as f64;
    if d > 0.0 && d64 >= range.min_m && d64 <= range.max_m && d.is_finite() {
        let w = 1.0 / d;
        // 1/d of a subnormal-free finite positive f32 is finite except for the
        // tiniest denormals; those are not depths any sensor reports.
        if w.is_finite() {
            return w;
        }
    }
    if d64 > range.max_m && d.is_finite() {
        return FAR;
    }
    INVALID
}

/// Fill `grid` with the inverse depth of `image` sampled every `step` pixels.
pub fn fill_grid(
    image: &DepthImage,
    axis: TrackAxis,
    step: usize,
    range: &DepthRange,
    grid: &mut InvGrid,
) {
    fill(image, axis, step, range, grid, false);
}

/// [`fill_grid`], and for a Z16 frame of at least [`COUNT_MIN_SAMPLES`]
/// samples a count of each sampled Z16 value made in the same pass, from
/// which [`InvGrid::select2`] takes the percentiles without another pass.
pub fn fill_grid_counted(
    image: &DepthImage,
    axis: TrackAxis,
    step: usize,
    range: &DepthRange,
    grid: &mut InvGrid,
) {
    fill(image, axis, step, range, grid, true);
}

/// Below this many samples the radix selection over the samples is cheaper
/// than clearing and scanning 65,536 counters (both are exact).
pub const COUNT_MIN_SAMPLES: usize = 1 << 15;

fn fill(
    image: &DepthImage,
    axis: TrackAxis,
    step: usize,
    range: &DepthRange,
    grid: &mut InvGrid,
    count: bool,
) {
    let step = step.max(1);
    grid.counted = false;
    let (w_img, h_img) = (image.width(), image.height());
    let (along_extent, across_extent) = match axis {
        TrackAxis::Rows => (w_img, h_img),
        TrackAxis::Columns => (h_img, w_img),
    };
    grid.step = step;
    grid.along_idx = sample_indices(along_extent, step);
    grid.across_idx = sample_indices(across_extent, step);
    grid.per_line = grid.along_idx.len();
    grid.lines = grid.across_idx.len();
    // Every sample is overwritten below: resizing to the same size writes nothing.
    grid.w.resize(grid.per_line * grid.lines, INVALID);
    match (image.data(), axis) {
        (DepthData::Z16 { data, scale_m }, _) => {
            let key = [
                scale_m.to_bits(),
                range.min_m.to_bits(),
                range.max_m.to_bits(),
            ];
            if grid.lut_key != Some(key) {
                let (lut, valid) = z16_table(*scale_m, range);
                grid.lut = lut;
                grid.lut_valid = valid;
                grid.lut_key = Some(key);
            }
            let lut = std::mem::take(&mut grid.lut);
            // A fixed-size view: a u16 index needs no bounds check.
            let table: &[f32; 65536] = lut.as_slice().try_into().expect("65536 entries");
            if count && grid.lut_valid.is_some() && grid.w.len() >= COUNT_MIN_SAMPLES {
                let mut hist = std::mem::take(&mut grid.hist);
                hist.clear();
                hist.resize(2 * 65536, 0);
                let counts: &mut [u32; 2 * 65536] =
                    hist.as_mut_slice().try_into().expect("2 × 65536 entries");
                // One walk: each value is converted, counted and tested once.
                // Two counts, samples alternating between them: flat ground
                // is a run of equal values, and one counter would make each
                // increment wait on the one before (the fill's largest cost).
                let mut valid = 0usize;
                let mut other = 0usize;
                fill_lines(grid, axis, w_img, data, |z: u16| {
                    counts[(z as usize | other) & (2 * 65536 - 1)] += 1;
                    other ^= 65536;
                    let w = table[z as usize];
                    valid += (w >= 0.0) as usize;
                    w
                });
                let (first, second) = hist.split_at_mut(65536);
                first
                    .iter_mut()
                    .zip(second.iter())
                    .for_each(|(a, b)| *a += b);
                hist.truncate(65536);
                // No return, saturation and every value past the range's end.
                let hi = grid.lut_valid.map_or(usize::MAX, |(_, hi)| hi);
                grid.far = hist[0] as usize
                    + hist
                        .get(hi + 1..)
                        .map_or(0, |t| t.iter().map(|&c| c as usize).sum());
                grid.hist = hist;
                grid.lut = lut;
                // `lut_valid` holds no SKY entry.
                grid.valid = valid;
                grid.sky = 0;
                grid.counted = true;
                return;
            }
            fill_lines(grid, axis, w_img, data, |z: u16| table[z as usize]);
            grid.lut = lut;
        }
        (DepthData::Metres(data), _) => {
            fill_lines(grid, axis, w_img, data, |d| inv_from_metres(d, range));
        }
    }
    // Counted per line in u32 lanes, which vectorise four wide.
    let (mut valid, mut sky, mut far) = (0usize, 0usize, 0usize);
    for line in grid.w.chunks_exact(grid.per_line.max(1)) {
        valid += line.iter().map(|&w| (w >= 0.0) as u32).sum::<u32>() as usize;
        sky += line.iter().map(|&w| (w == SKY) as u32).sum::<u32>() as usize;
        far += line.iter().map(|&w| (w == FAR) as u32).sum::<u32>() as usize;
    }
    grid.valid = valid;
    grid.sky = sky;
    grid.far = far;
}

/// Inverse depth of each Z16 value: no return (0), saturation (`u16::MAX`) and
/// depths past `range` are `FAR`, depths nearer than it `INVALID`. Also the valid values `lo..=hi` when
/// each of them maps to a finite positive inverse depth (what counting needs).
fn z16_table(scale_m: f64, range: &DepthRange) -> (Vec<f32>, Option<(usize, usize)>) {
    let lo = (range.min_m / scale_m).ceil().max(1.0);
    let hi = (range.max_m / scale_m).floor().min((u16::MAX - 1) as f64);
    let inv_scale = (1.0 / scale_m) as f32;
    let table: Vec<f32> = (0..=u16::MAX)
        .map(|z| {
            let zf = z as f64;
            if zf >= lo && zf <= hi {
                inv_scale / z as f32
            } else if z == 0 || zf > hi {
                FAR
            } else {
                INVALID
            }
        })
        .collect();
    let valid = (lo <= hi)
        .then_some((lo as usize, hi as usize))
        .filter(|&(l, h)| table[l..=h].iter().all(|&w| w > 0.0 && w.is_finite()));
    (table, valid)
}

/// Converts the sampled pixels line by line; the common case (rows along
/// track, every pixel) is a straight map over each row, which vectorises.
fn fill_lines<T: Copy>(
    grid: &mut InvGrid,
    axis: TrackAxis,
    w_img: usize,
    data: &[T],
    mut convert: impl FnMut(T) -> f32,
) {
    let per_line = grid.per_line;
    for (a, out) in grid.w.chunks_exact_mut(per_line).enumerate() {
        let across = grid.across_idx[a];
        match axis {
            TrackAxis::Rows if grid.step == 1 => {
                let row = &data[across * w_img..across * w_img + per_line];
                for (o, &z) in out.iter_mut().zip(row) {
                    *o = convert(z);
                }
            }
            TrackAxis::Rows => {
                let row = &data[across * w_img..(across + 1) * w_img];
                for (o, &j) in out.iter_mut().zip(&grid.along_idx) {
                    *o = convert(row[j]);
                }
            }
            TrackAxis::Columns => {
                for (o, &j) in out.iter_mut().zip(&grid.along_idx) {
                    *o = convert(data[j * w_img + across]);
                }
            }
        }
    }
}

/// Scratch for radix selection: four interleaved 2048-bin histograms (so runs
/// of equal values do not serialise on one counter) and the candidate values
/// of the two targets.
#[derive(Debug, Clone)]
pub struct Selector {
    hist: Vec<u32>,
    cand: [Vec<f32>; 2],
}

impl Default for Selector {
    fn default() -> Self {
        Selector {
            hist: vec![0; 4 * BINS],
            cand: [Vec::new(), Vec::new()],
        }
    }
}

const BINS: usize = 2048;

/// Histogram of `(bits >> shift) & mask` into `hist[..BINS]`.
fn histogram(hist: &mut [u32], values: &[f32], shift: u32, mask: u32) {
    count4::<BINS>(hist, values, |w| ((w.to_bits() >> shift) & mask) as usize);
}

/// Counts `values` by `bin` into `hist[..N]` (zeroed first), leaving out a
/// value whose bin is `N` or more. `hist` holds four counts of `N` bins, one
/// per lane of four consecutive values, summed into the first at the end: a
/// run of equal values (flat ground) does not wait on one counter.
pub(crate) fn count4<const N: usize>(hist: &mut [u32], values: &[f32], bin: impl Fn(f32) -> usize) {
    hist.iter_mut().for_each(|c| *c = 0);
    let (h0, rest) = hist.split_at_mut(N);
    let (h1, rest) = rest.split_at_mut(N);
    let (h2, h3) = rest.split_at_mut(N);
    let mut chunks = values.chunks_exact(4);
    for c in &mut chunks {
        for (h, &v) in [&mut *h0, &mut *h1, &mut *h2, &mut *h3].into_iter().zip(c) {
            if let Some(n) = h.get_mut(bin(v)) {
                *n += 1;
            }
        }
    }
    for &v in chunks.remainder() {
        if let Some(n) = h0.get_mut(bin(v)) {
            *n += 1;
        }
    }
    for i in 0..N {
        h0[i] += h1[i] + h2[i] + h3[i];
    }
}

fn find_bin(hist: &[u32], mut rank: u64) -> (usize, u64) {
    for (b, &c) in hist.iter().enumerate() {
        let c = c as u64;
        if rank < c {
            return (b, rank);
        }
        rank -= c;
    }
    // Callers pass rank < total, so the loop always returns; stay total anyway.
    (hist.len() - 1, 0)
}

impl Selector {
    /// Exact order statistics (0-based `ranks`) of the valid values of a slice
    /// whose values are `INVALID`, `SKY` or positive; the sky counts only with
    /// `include_sky`. `None` when fewer values pass than a rank needs.
    pub fn select2(
        &mut self,
        values: &[f32],
        include_sky: bool,
        ranks: [u64; 2],
    ) -> Option<[f32; 2]> {
        // Level 1: top 11 bits. Negative values (INVALID) fall in bins >= 1024.
        histogram(&mut self.hist, values, 21, 0x7FF);
        if !include_sky {
            // SKY is +0.0, in bin 0 with the subnormals, which no depth produces.
            self.hist[0] = 0;
        }
        let total: u64 = self.hist[..1024].iter().map(|&c| c as u64).sum();
        if ranks.iter().any(|&r| r >= total) {
            return None;
        }
        let mut prefix = [0u32; 2];
        let mut rem = [0u64; 2];
        for t in 0..2 {
            let (b, r) = find_bin(&self.hist[..1024], ranks[t]);
            prefix[t] = b as u32;
            rem[t] = r;
        }
        // The candidates of each target: the values in its level-1 bin.
        let same = prefix[0] == prefix[1];
        let [c0, c1] = &mut self.cand;
        c0.clear();
        c1.clear();
        for &w in values {
            let top = w.to_bits() >> 21;
            if top == prefix[0] {
                c0.push(w);
            } else if !same && top == prefix[1] {
                c1.push(w);
            }
        }
        let mut out = [0f32; 2];
        for t in 0..2 {
            let src = if same { 0 } else { t };
            // Level 2: the next 11 bits; level 3: the last 10, on the survivors.
            histogram(&mut self.hist, &self.cand[src], 10, 0x7FF);
            let (b2, r2) = find_bin(&self.hist[..BINS], rem[t]);
            let p22 = (prefix[t] << 11) | b2 as u32;
            let keep = |w: &f32| w.to_bits() >> 10 == p22;
            let [c0, c1] = &mut self.cand;
            let survivors: &[f32] = if same {
                // Both targets share c0; filter into the unused c1.
                c1.clear();
                c1.extend(c0.iter().copied().filter(keep));
                c1
            } else if t == 0 {
                c0.retain(keep);
                c0
            } else {
                c1.retain(keep);
                c1
            };
            histogram(&mut self.hist, survivors, 0, 0x3FF);
            let (b3, _) = find_bin(&self.hist[..1024], r2);
            out[t] = f32::from_bits((p22 << 10) | b3 as u32);
        }
        Some(out)
    }
}

/// Ranks of the low and high percentiles among `n` values (`p` in [0, 1]):
/// the low one rounds down and the high one up, so the robust range never
/// shrinks below what the percentiles name.
pub fn percentile_ranks(n: u64, p_low: f64, p_high: f64) -> [u64; 2] {
    if n == 0 {
        return [0, 0];
    }
    let last = (n - 1) as f64;
    let lo = (p_low * last).floor().clamp(0.0, last) as u64;
    let hi = (p_high * last).ceil().clamp(0.0, last) as u64;
    [lo, hi.max(lo)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Z16 frame of smooth depth with noise, no-return and saturated pixels.
    fn z16_frame(w: usize, h: usize, seed: u64) -> DepthImage {
        let mut s = seed;
        let data = (0..w * h)
            .map(|i| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let r = (s >> 33) as u32;
                match r % 50 {
                    0 => 0,
                    1 => u16::MAX,
                    // Runs of equal values (flat ground) and a spread (walls).
                    2..=20 => 20_000,
                    _ => (5_000 + (i % w) * 40 + (r % 700) as usize) as u16,
                }
            })
            .collect();
        DepthImage::new(
            w,
            h,
            DepthData::Z16 {
                data,
                scale_m: 0.001,
            },
        )
        .unwrap()
    }

    #[test]
    fn counted_percentiles_equal_the_selection() {
        let mut sel = Selector::default();
        let ranges = [
            DepthRange::default(),
            DepthRange {
                min_m: 6.0,
                max_m: 25.0,
            },
        ];
        for (seed, (w, h)) in [(1u64, (320usize, 240usize)), (2, (256, 160))] {
            let img = z16_frame(w, h, seed);
            for range in &ranges {
                for (axis, step) in [(TrackAxis::Rows, 1), (TrackAxis::Columns, 1)] {
                    let (mut plain, mut counted) = (InvGrid::default(), InvGrid::default());
                    fill_grid(&img, axis, step, range, &mut plain);
                    fill_grid_counted(&img, axis, step, range, &mut counted);
                    assert!(counted.counted, "{w}x{h} counted");
                    assert_eq!(plain.w, counted.w);
                    assert_eq!((plain.valid, plain.sky), (counted.valid, counted.sky));
                    let n = plain.valid as u64;
                    let mut ranks = vec![
                        percentile_ranks(n, 0.005, 0.995),
                        [0, n - 1],
                        [n / 2, n / 2],
                        [1, n - 2],
                    ];
                    ranks.extend((0..20).map(|k| [k * n / 20, (n - 1) - k * n / 40]));
                    for r in ranks {
                        for sky in [false, true] {
                            assert_eq!(
                                counted.select2(&mut sel, sky, r),
                                sel.select2(&plain.w, sky, r),
                                "{w}x{h} {range:?} {axis:?} ranks {r:?}"
                            );
                        }
                    }
                    assert_eq!(counted.select2(&mut sel, false, [0, n]), None);
                }
            }
        }
    }

    #[test]
    fn small_grids_and_metres_are_not_counted() {
        let img = z16_frame(64, 48, 7);
        let mut g = InvGrid::default();
        fill_grid_counted(&img, TrackAxis::Rows, 1, &DepthRange::default(), &mut g);
        assert!(!g.counted);
        let big = z16_frame(320, 240, 8);
        fill_grid_counted(&big, TrackAxis::Rows, 1, &DepthRange::default(), &mut g);
        assert!(g.counted);
        // A later plain fill drops the count of the earlier frame.
        fill_grid(&big, TrackAxis::Rows, 1, &DepthRange::default(), &mut g);
        assert!(!g.counted);
    }
}
