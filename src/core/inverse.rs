//! Inverse depth on a decimated, track-major sample grid, and exact order
//! statistics of it in O(n) by a three-level radix histogram (no sort).
//!
//! Invariant: a grid value is `INVALID` (negative), `SKY` (0.0) or a finite
//! positive inverse depth in 1/m. Non-negative `f32` bit patterns order like
//! their values, which is what makes the radix selection exact.

use super::depth::{DepthData, DepthImage, TrackAxis};

/// Marker for a masked pixel (no return, saturated, NaN, out of range).
pub const INVALID: f32 = -1.0;
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
}

impl InvGrid {
    pub fn line(&self, a: usize) -> &[f32] {
        &self.w[a * self.per_line..(a + 1) * self.per_line]
    }
    pub fn samples(&self) -> usize {
        self.w.len()
    }
}

/// Sample indices for a stride `step` over `extent` pixels: the centre of each block.
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
    let step = step.max(1);
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
    grid.w.clear();
    grid.w.reserve(grid.per_line * grid.lines);
    let index = |along: usize, across: usize| match axis {
        TrackAxis::Rows => across * w_img + along,
        TrackAxis::Columns => along * w_img + across,
    };
    match image.data() {
        DepthData::Z16 { data, scale_m } => {
            // Depth limits become integer limits once, so the inner loop is one
            // compare and one division.
            let lo = (range.min_m / scale_m).ceil().max(1.0);
            let hi = (range.max_m / scale_m).floor().min((u16::MAX - 1) as f64);
            let (lo, hi) = if lo <= hi {
                (lo as u16, hi as u16)
            } else {
                (1, 0)
            };
            let inv_scale = (1.0 / scale_m) as f32;
            for &a in &grid.across_idx {
                for &j in &grid.along_idx {
                    let z = data[index(j, a)];
                    let w = if z >= lo && z <= hi {
                        inv_scale / z as f32
                    } else {
                        INVALID
                    };
                    grid.w.push(w);
                }
            }
        }
        DepthData::Metres(data) => {
            for &a in &grid.across_idx {
                for &j in &grid.along_idx {
                    grid.w.push(inv_from_metres(data[index(j, a)], range));
                }
            }
        }
    }
    let mut valid = 0usize;
    let mut sky = 0usize;
    for &w in &grid.w {
        valid += (w >= 0.0) as usize;
        sky += (w == SKY) as usize;
    }
    grid.valid = valid;
    grid.sky = sky;
}

/// Scratch for radix selection (three levels of 2048 bins, two targets).
#[derive(Debug, Clone)]
pub struct Selector {
    hist: Vec<u32>,
    hist2: [Vec<u32>; 2],
}

impl Default for Selector {
    fn default() -> Self {
        Selector {
            hist: vec![0; 2048],
            hist2: [vec![0; 2048], vec![0; 2048]],
        }
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
    /// Exact order statistics (0-based `ranks` among the values `>= floor`)
    /// of a slice whose values are `INVALID`, `SKY` or positive. `floor` is
    /// `0.0` to include the sky, or the smallest positive `f32` to exclude it.
    /// Returns `None` when fewer values pass than a rank needs.
    pub fn select2(
        &mut self,
        values: &[f32],
        include_sky: bool,
        ranks: [u64; 2],
    ) -> Option<[f32; 2]> {
        // Level 1: top 11 bits. Negative values (INVALID) fall in bins >= 1024.
        self.hist.iter_mut().for_each(|c| *c = 0);
        for &w in values {
            self.hist[(w.to_bits() >> 21) as usize] += 1;
        }
        if !include_sky {
            // SKY is +0.0, the only value in bin 0 with a zero mantissa; bin 0 also
            // holds subnormals, which no depth produces, so drop it whole.
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
        // Levels 2 and 3: narrow each target by 11 then 10 more bits.
        for (shift, width_bits) in [(10u32, 11u32), (0, 10)] {
            for h in self.hist2.iter_mut() {
                h.iter_mut().for_each(|c| *c = 0);
            }
            let mask = (1u32 << width_bits) - 1;
            let top_shift = shift + width_bits;
            for &w in values {
                let bits = w.to_bits();
                let top = bits >> top_shift;
                let low = ((bits >> shift) & mask) as usize;
                if top == prefix[0] {
                    self.hist2[0][low] += 1;
                }
                if top == prefix[1] {
                    self.hist2[1][low] += 1;
                }
            }
            for t in 0..2 {
                let (b, r) = find_bin(&self.hist2[t][..=mask as usize], rem[t]);
                prefix[t] = (prefix[t] << width_bits) | b as u32;
                rem[t] = r;
            }
        }
        Some([f32::from_bits(prefix[0]), f32::from_bits(prefix[1])])
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
