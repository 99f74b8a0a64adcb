//! Image quality: PSNR and SSIM (Wang et al. 2004: 11×11 Gaussian window,
//! σ = 1.5, K1 = 0.01, K2 = 0.03, mean over the windows fully inside the
//! image) on single-channel images with values in `[0, peak]`.

/// PSNR in dB; `+inf` for identical images.
pub fn psnr(a: &[f32], b: &[f32], peak: f64) -> f64 {
    assert_eq!(a.len(), b.len(), "psnr of images of different sizes");
    let mse = mse(a, b);
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / mse).log10()
    }
}

pub fn mse(a: &[f32], b: &[f32]) -> f64 {
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            let d = *x as f64 - *y as f64;
            d * d
        })
        .sum();
    s / a.len().max(1) as f64
}

pub const SSIM_WINDOW: usize = 11;
pub const SSIM_SIGMA: f64 = 1.5;
pub const SSIM_K1: f64 = 0.01;
pub const SSIM_K2: f64 = 0.03;

/// The normalised 1-D Gaussian of the SSIM window.
pub fn gaussian_window() -> [f64; SSIM_WINDOW] {
    let mut g = [0.0; SSIM_WINDOW];
    let c = (SSIM_WINDOW / 2) as f64;
    for (i, v) in g.iter_mut().enumerate() {
        let x = i as f64 - c;
        *v = (-x * x / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= s);
    g
}

/// Mean SSIM of `a` against `b` (`width`×`height`, row-major), dynamic range
/// `peak`; `None` for images smaller than the window.
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize, peak: f64) -> Option<f64> {
    ssim_map(a, b, width, height, peak).map(|m| m.mean())
}

/// SSIM of every window fully inside the image, row-major; the window at
/// `(row, col)` of the map is centred on pixel `(row + 5, col + 5)`.
#[derive(Debug, Clone)]
pub struct SsimMap {
    pub values: Vec<f64>,
    pub width: usize,
    pub height: usize,
}

impl SsimMap {
    /// The mean over the windows: the image's SSIM.
    pub fn mean(&self) -> f64 {
        self.values.iter().sum::<f64>() / self.values.len() as f64
    }
}

/// The per-window SSIM of `a` against `b` ([`ssim`] is its mean); `None` for
/// images smaller than the window.
pub fn ssim_map(a: &[f32], b: &[f32], width: usize, height: usize, peak: f64) -> Option<SsimMap> {
    assert_eq!(a.len(), width * height);
    assert_eq!(b.len(), width * height);
    if width < SSIM_WINDOW || height < SSIM_WINDOW {
        return None;
    }
    let c1 = (SSIM_K1 * peak).powi(2);
    let c2 = (SSIM_K2 * peak).powi(2);
    let ow = width - SSIM_WINDOW + 1;
    // Horizontal pass of the five moments, then vertical, in f64. Each moment
    // is its own plane and each tap a pass over a whole line, so the inner
    // loops run over contiguous values and vectorise; every output still sums
    // its taps in the same order from zero, so the values are the same bits
    // as one window at a time.
    HORIZONTAL.with_borrow_mut(|scratch| {
        scratch.clear();
        scratch.resize(5 * ow * height, 0.0);
        let planes = scratch.chunks_exact_mut(ow * height);
        let hz: [&mut [f64]; 5] = planes.collect::<Vec<_>>().try_into().expect("five planes");
        moments_map(a, b, width, height, hz, c1, c2)
    })
}

thread_local! {
    /// [`ssim_map`]'s horizontal planes, kept between calls: five planes of a
    /// frame's size freshly allocated for every map were returned to the
    /// system and faulted in again each time (`alfd eval` scores thousands).
    static HORIZONTAL: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// [`ssim_map`] on its zeroed horizontal planes.
fn moments_map(
    a: &[f32],
    b: &[f32],
    width: usize,
    height: usize,
    mut hz: [&mut [f64]; 5],
    c1: f64,
    c2: f64,
) -> Option<SsimMap> {
    let g = gaussian_window();
    let ow = width - SSIM_WINDOW + 1;
    let oh = height - SSIM_WINDOW + 1;
    for r in 0..height {
        let ra = &a[r * width..(r + 1) * width];
        let rb = &b[r * width..(r + 1) * width];
        let [h0, h1, h2, h3, h4] = hz.each_mut().map(|p| &mut p[r * ow..(r + 1) * ow]);
        for (k, &gk) in g.iter().enumerate() {
            let (xs, ys) = (&ra[k..k + ow], &rb[k..k + ow]);
            for c in 0..ow {
                let (x, y) = (xs[c] as f64, ys[c] as f64);
                h0[c] += gk * x;
                h1[c] += gk * y;
                h2[c] += gk * x * x;
                h3[c] += gk * y * y;
                h4[c] += gk * x * y;
            }
        }
    }
    let mut values = Vec::with_capacity(ow * oh);
    let mut m = [(); 5].map(|_| vec![0f64; ow]);
    for r in 0..oh {
        for plane in &mut m {
            plane.fill(0.0);
        }
        for (k, &gk) in g.iter().enumerate() {
            for (acc, h) in m.iter_mut().zip(&hz) {
                let line = &h[(r + k) * ow..(r + k + 1) * ow];
                for (o, &v) in acc.iter_mut().zip(line) {
                    *o += gk * v;
                }
            }
        }
        values.extend(
            (0..ow).map(|c| ssim_of_moments([m[0][c], m[1][c], m[2][c], m[3][c], m[4][c]], c1, c2)),
        );
    }
    Some(SsimMap {
        values,
        width: ow,
        height: oh,
    })
}

/// SSIM of one window from its weighted moments `[μx, μy, E x², E y², E xy]`.
#[inline]
pub fn ssim_of_moments(m: [f64; 5], c1: f64, c2: f64) -> f64 {
    let (mx, my) = (m[0], m[1]);
    let sxx = m[2] - mx * mx;
    let syy = m[3] - my * my;
    let sxy = m[4] - mx * my;
    ((2.0 * mx * my + c1) * (2.0 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The moments one window at a time, as `ssim_map` computed them before
    /// its planes were split: the same bits are expected, not merely close ones.
    fn ssim_map_by_window(a: &[f32], b: &[f32], width: usize, height: usize) -> Vec<f64> {
        let g = gaussian_window();
        let (c1, c2) = ((SSIM_K1).powi(2), (SSIM_K2).powi(2));
        let (ow, oh) = (width - SSIM_WINDOW + 1, height - SSIM_WINDOW + 1);
        let mut hz = vec![[0f64; 5]; ow * height];
        for r in 0..height {
            for c in 0..ow {
                let mut m = [0f64; 5];
                for (k, gk) in g.iter().enumerate() {
                    let x = a[r * width + c + k] as f64;
                    let y = b[r * width + c + k] as f64;
                    m[0] += gk * x;
                    m[1] += gk * y;
                    m[2] += gk * x * x;
                    m[3] += gk * y * y;
                    m[4] += gk * x * y;
                }
                hz[r * ow + c] = m;
            }
        }
        let mut values = Vec::new();
        for r in 0..oh {
            for c in 0..ow {
                let mut m = [0f64; 5];
                for (k, gk) in g.iter().enumerate() {
                    for (j, v) in m.iter_mut().enumerate() {
                        *v += gk * hz[(r + k) * ow + c][j];
                    }
                }
                values.push(ssim_of_moments(m, c1, c2));
            }
        }
        values
    }

    #[test]
    fn the_planes_give_the_same_bits_as_one_window_at_a_time() {
        let (w, h) = (53, 31);
        let mut s = 12345u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let a: Vec<f32> = (0..w * h).map(|_| next()).collect();
        let b: Vec<f32> = a.iter().map(|&x| 0.7 * x + 0.3 * next()).collect();
        let got = ssim_map(&a, &b, w, h, 1.0).unwrap();
        let want = ssim_map_by_window(&a, &b, w, h);
        assert_eq!((got.width, got.height), (w - 10, h - 10));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got.values), bits(&want));
    }
}
