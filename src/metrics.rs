//! Image quality: PSNR and SSIM (Wang et al. 2004: 11×11 Gaussian window,
//! σ = 1.5, K1 = 0.01, K2 = 0.03, mean over the windows fully inside the
//! image) on single-channel images with values in `[0, peak]`.

/// PSNR in dB; `+inf` for identical images.
pub fn psnr(a: &[f32], b: &[f32], peak: f64) -> f64 {
    assert_eq!(a.len(), b.len(), "psnr of images of different sizes");
    psnr_of_mse(mse(a, b), peak)
}

/// PSNR (dB) of a mean squared error ([`mse`]) at `peak`; infinite for no error.
pub fn psnr_of_mse(mse: f64, peak: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / mse).log10()
    }
}

pub fn mse(a: &[f32], b: &[f32]) -> f64 {
    mse_with(a, b, |_, _| {})
}

/// [`mse`], handing each pixel's squared error to `each` (pixel index, squared error) on the
/// way: a caller that also sums them its own way (per class) does it in the same pass, as two
/// independent chains of additions that take the time of one.
#[inline]
pub fn mse_with(a: &[f32], b: &[f32], mut each: impl FnMut(usize, f64)) -> f64 {
    let mut s = 0.0f64;
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        let d = *x as f64 - *y as f64;
        let sq = d * d;
        s += sq;
        each(k, sq);
    }
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
    ssim_maps([a], b, width, height, peak).map(|[m]| m)
}

/// [`ssim_map`] of each of `a` against the same `b`, the same bits: `b`'s own moments are
/// made once (two of the five planes of each map).
pub fn ssim_maps<const N: usize>(
    a: [&[f32]; N],
    b: &[f32],
    width: usize,
    height: usize,
    peak: f64,
) -> Option<[SsimMap; N]> {
    for x in a {
        assert_eq!(x.len(), width * height);
    }
    assert_eq!(b.len(), width * height);
    if width < SSIM_WINDOW || height < SSIM_WINDOW {
        return None;
    }
    let c1 = (SSIM_K1 * peak).powi(2);
    let c2 = (SSIM_K2 * peak).powi(2);
    Some(MOMENTS.with_borrow_mut(|scratch| moments_maps(a, b, width, height, scratch, c1, c2)))
}

thread_local! {
    /// [`ssim_maps`]'s working lines, kept between calls (`alfd eval` scores thousands of
    /// maps; freshly allocated, their pages were faulted in again each time).
    static MOMENTS: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The moments, horizontal pass then vertical, in f64: `b`'s mean and mean square, and each
/// `a`'s mean, mean square and product with `b`. Each moment is its own line and each tap a
/// pass over a whole line, so the inner loops run over contiguous values and vectorise; every
/// output sums its taps in the same order from zero, so the values are the same bits as one
/// window at a time. Only the last `SSIM_WINDOW` rows of the horizontal pass are kept (a
/// ring): a vertical window needs no more, and the whole planes did not stay in cache.
///
/// Compiled for AVX2 too, taken where the CPU has it: the same IEEE operations in the same
/// order four lanes wide (Rust fuses no multiply-add), so the same bits.
fn moments_maps<const N: usize>(
    a: [&[f32]; N],
    b: &[f32],
    width: usize,
    height: usize,
    scratch: &mut Vec<f64>,
    c1: f64,
    c2: f64,
) -> [SsimMap; N] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above, cached by std).
        return unsafe { moments_maps_avx2(a, b, width, height, scratch, c1, c2) };
    }
    moments_maps_portable(a, b, width, height, scratch, c1, c2)
}

/// [`moments_maps_portable`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn moments_maps_avx2<const N: usize>(
    a: [&[f32]; N],
    b: &[f32],
    width: usize,
    height: usize,
    scratch: &mut Vec<f64>,
    c1: f64,
    c2: f64,
) -> [SsimMap; N] {
    moments_maps_portable(a, b, width, height, scratch, c1, c2)
}

#[inline(always)]
fn moments_maps_portable<const N: usize>(
    a: [&[f32]; N],
    b: &[f32],
    width: usize,
    height: usize,
    scratch: &mut Vec<f64>,
    c1: f64,
    c2: f64,
) -> [SsimMap; N] {
    let g = gaussian_window();
    let ow = width - SSIM_WINDOW + 1;
    let oh = height - SSIM_WINDOW + 1;
    // Moment lines: 0 `b`, 1 `b²`, then per `a` (`2 + 3n`): `a`, `a²`, `a·b`; a ring of
    // `SSIM_WINDOW` horizontal rows, then one vertical row.
    let planes = 2 + 3 * N;
    let ring_len = planes * ow * SSIM_WINDOW;
    scratch.clear();
    scratch.resize(ring_len + planes * ow, 0.0);
    let (ring, vertical) = scratch.split_at_mut(ring_len);
    let mut values: [Vec<f64>; N] = std::array::from_fn(|_| Vec::with_capacity(ow * oh));
    for r in 0..height {
        // Horizontal: row `r` into its slot of the ring, from zero.
        let slot = &mut ring[(r % SSIM_WINDOW) * planes * ow..][..planes * ow];
        slot.fill(0.0);
        let (hb, ha) = slot.split_at_mut(2 * ow);
        let (h0, h1) = hb.split_at_mut(ow);
        let rb = &b[r * width..(r + 1) * width];
        for (k, &gk) in g.iter().enumerate() {
            let ys = &rb[k..k + ow];
            for c in 0..ow {
                let y = ys[c] as f64;
                h0[c] += gk * y;
                h1[c] += gk * y * y;
            }
        }
        for (x_img, hx) in a.iter().zip(ha.chunks_exact_mut(3 * ow)) {
            let ra = &x_img[r * width..(r + 1) * width];
            let (hm, rest) = hx.split_at_mut(ow);
            let (hsq, hxy) = rest.split_at_mut(ow);
            for (k, &gk) in g.iter().enumerate() {
                let (xs, ys) = (&ra[k..k + ow], &rb[k..k + ow]);
                for c in 0..ow {
                    let (x, y) = (xs[c] as f64, ys[c] as f64);
                    hm[c] += gk * x;
                    hsq[c] += gk * x * x;
                    hxy[c] += gk * x * y;
                }
            }
        }
        // Vertical: once the ring holds the window's rows, output row `r + 1 - SSIM_WINDOW`.
        let Some(out_r) = (r + 1).checked_sub(SSIM_WINDOW) else {
            continue;
        };
        vertical.fill(0.0);
        for (k, &gk) in g.iter().enumerate() {
            let src = &ring[((out_r + k) % SSIM_WINDOW) * planes * ow..][..planes * ow];
            for (o, &v) in vertical.iter_mut().zip(src) {
                *o += gk * v;
            }
        }
        let (mb, mb2) = (&vertical[..ow], &vertical[ow..2 * ow]);
        for (n, out) in values.iter_mut().enumerate() {
            let m = &vertical[(2 + 3 * n) * ow..(5 + 3 * n) * ow];
            let (mx, mxx, mxy) = (&m[..ow], &m[ow..2 * ow], &m[2 * ow..]);
            out.extend(
                (0..ow).map(|c| ssim_of_moments([mx[c], mb[c], mxx[c], mb2[c], mxy[c]], c1, c2)),
            );
        }
    }
    values.map(|values| SsimMap {
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
        // Two images against one: each map as it is alone.
        let c: Vec<f32> = b.iter().map(|&x| 1.0 - x * next()).collect();
        let [mb, mc] = ssim_maps([&b, &c], &a, w, h, 1.0).unwrap();
        assert_eq!(bits(&mb.values), bits(&ssim_map_by_window(&b, &a, w, h)));
        assert_eq!(bits(&mc.values), bits(&ssim_map_by_window(&c, &a, w, h)));
        // The AVX2 build (taken on this machine when it has AVX2) and the portable one.
        let (c1, c2) = (SSIM_K1.powi(2), SSIM_K2.powi(2));
        let got = moments_maps([&b, &c], &a, w, h, &mut Vec::new(), c1, c2);
        let want = moments_maps_portable([&b, &c], &a, w, h, &mut Vec::new(), c1, c2);
        for (g, p) in got.iter().zip(&want) {
            assert_eq!(bits(&g.values), bits(&p.values));
        }
    }
}
