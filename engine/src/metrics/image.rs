//! Image quality: PSNR and SSIM, plain and masked (DTU protocol).
//!
//! Images are row-major, interleaved, `channels` floats per pixel in `[0, 1]`
//! (`ImageRgb::data`, or `RenderedView::rgb.as_flattened()`); everything is computed in
//! `f64`.
//!
//! # PSNR
//! `MSE = mean over all pixels and channels of (a - b)^2`,
//! `PSNR = -10 log10(max(MSE, 1e-10))` dB (data range 1; the floor caps identical
//! images at 100 dB, where scikit-image would return `inf`, so numbers stay finite in
//! JSON). [`psnr_from_mse`] is the one conversion.
//!
//! # SSIM
//! Exactly scikit-image's `structural_similarity(a, b, gaussian_weights=True,
//! sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1)` (Wang et al.
//! 2004), checked against it in `tests/metrics_image.rs` (fixtures from
//! `tools/metrics-fixtures/make_fixtures.py`). Per channel:
//! * `G` = SciPy's `gaussian_filter(x, sigma=1.5, truncate=3.5, mode='reflect')`: the
//!   separable 11-tap kernel `w_i ~ exp(-i^2 / (2 sigma^2))`, `i = -5..=5`, normalised
//!   to sum 1, applied along columns then rows, the image extended by half-sample
//!   symmetric reflection (`d c b a | a b c d | d c b a`);
//! * `mu_a = G(a)`, `mu_b = G(b)`, `var_a = G(a^2) - mu_a^2`, `var_b = G(b^2) - mu_b^2`,
//!   `cov = G(ab) - mu_a mu_b` (population covariance);
//! * `S = (2 mu_a mu_b + C1)(2 cov + C2) / ((mu_a^2 + mu_b^2 + C1)(var_a + var_b + C2))`
//!   with `C1 = (0.01)^2`, `C2 = (0.03)^2`;
//! * the channel's SSIM is the mean of `S` over the image with a border of
//!   `(11 - 1) / 2 = 5` pixels cropped on every side.
//!
//! The image's SSIM is the mean over channels. Images smaller than 11x11 are an error
//! (scikit-image refuses them too).
//!
//! # Masked (DTU, RegNeRF protocol; NOTES.md section 2)
//! With an object mask `m` in `[0, 1]`: PSNR from the mask-weighted MSE
//! `sum_p m_p sum_c (a - b)^2 / (channels * sum_p m_p)` (for a binary mask: the MSE
//! over mask pixels only); SSIM of the composites `a m + (1 - m)` and `b m + (1 - m)`
//! (both images over white outside the mask).

use super::MetricsError;

/// Gaussian standard deviation of the SSIM window.
pub const SSIM_SIGMA: f64 = 1.5;
/// Radius of the SSIM window: `int(3.5 * 1.5 + 0.5)` (scikit-image's `truncate=3.5`),
/// an 11x11 window; also the border cropped before averaging.
pub const SSIM_RADIUS: usize = 5;
/// SSIM stabilising constants `K1`, `K2` (data range 1: `C = K^2`).
pub const SSIM_K1: f64 = 0.01;
pub const SSIM_K2: f64 = 0.03;
/// The MSE floor of [`psnr_from_mse`] (PSNR cap of 100 dB).
pub const MIN_MSE: f64 = 1e-10;

/// PSNR and SSIM of one RGB image pair.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImageMetrics {
    /// dB, data range 1.
    pub psnr: f64,
    /// Mean SSIM over the channels, in `[-1, 1]`.
    pub ssim: f64,
}

/// PSNR in dB of a mean squared error on `[0, 1]` data: `-10 log10(max(mse, 1e-10))`.
pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.max(MIN_MSE).log10()
}

/// Mean of `(a - b)^2` over all values.
pub fn mse(a: &[f32], b: &[f32]) -> Result<f64, MetricsError> {
    MetricsError::check_len("second image", a.len(), b.len())?;
    if a.is_empty() {
        return Err(MetricsError::Empty { what: "image" });
    }
    Ok(a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>() / a.len() as f64)
}

/// PSNR of two images of the same size (any layout: all values count equally).
pub fn psnr(a: &[f32], b: &[f32]) -> Result<f64, MetricsError> {
    Ok(psnr_from_mse(mse(a, b)?))
}

/// SSIM of two `width x height` images with `channels` interleaved channels: the mean
/// over channels of scikit-image's Gaussian-window SSIM (see the module docs).
pub fn ssim(width: u32, height: u32, channels: usize, a: &[f32], b: &[f32]) -> Result<f64, MetricsError> {
    let (w, h) = (width as usize, height as usize);
    MetricsError::check_len("first image", w * h * channels, a.len())?;
    MetricsError::check_len("second image", w * h * channels, b.len())?;
    let win = 2 * SSIM_RADIUS + 1;
    if w < win || h < win || channels == 0 {
        return Err(MetricsError::ImageTooSmall { width, height, min: win as u32 });
    }
    let kernel = gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS);
    let (c1, c2) = (SSIM_K1 * SSIM_K1, SSIM_K2 * SSIM_K2);
    let mut total = 0.0;
    for c in 0..channels {
        let x: Vec<f64> = a.iter().skip(c).step_by(channels).map(|&v| v as f64).collect();
        let y: Vec<f64> = b.iter().skip(c).step_by(channels).map(|&v| v as f64).collect();
        let blur = |img: Vec<f64>| filter_reflect(w, h, img, &kernel);
        let xx = x.iter().map(|v| v * v).collect();
        let yy = y.iter().map(|v| v * v).collect();
        let xy = x.iter().zip(&y).map(|(p, q)| p * q).collect();
        let (ux, uy) = (blur(x), blur(y));
        let (uxx, uyy, uxy) = (blur(xx), blur(yy), blur(xy));
        let mut sum = 0.0;
        for row in SSIM_RADIUS..h - SSIM_RADIUS {
            for col in SSIM_RADIUS..w - SSIM_RADIUS {
                let i = row * w + col;
                let (mx, my) = (ux[i], uy[i]);
                let (vx, vy, vxy) = (uxx[i] - mx * mx, uyy[i] - my * my, uxy[i] - mx * my);
                let num = (2.0 * mx * my + c1) * (2.0 * vxy + c2);
                let den = (mx * mx + my * my + c1) * (vx + vy + c2);
                sum += num / den;
            }
        }
        total += sum / ((h - 2 * SSIM_RADIUS) * (w - 2 * SSIM_RADIUS)) as f64;
    }
    Ok(total / channels as f64)
}

/// PSNR and SSIM of two RGB images (`3 * width * height` values each).
pub fn image_metrics(width: u32, height: u32, a: &[f32], b: &[f32]) -> Result<ImageMetrics, MetricsError> {
    Ok(ImageMetrics { psnr: psnr(a, b)?, ssim: ssim(width, height, 3, a, b)? })
}

/// DTU-protocol PSNR and SSIM of two RGB images under an object mask (one value per
/// pixel in `[0, 1]`): mask-weighted PSNR, SSIM of the white-composited images.
pub fn masked_image_metrics(
    width: u32,
    height: u32,
    a: &[f32],
    b: &[f32],
    mask: &[f32],
) -> Result<ImageMetrics, MetricsError> {
    let n = width as usize * height as usize;
    MetricsError::check_len("mask", n, mask.len())?;
    MetricsError::check_len("first image", 3 * n, a.len())?;
    MetricsError::check_len("second image", 3 * n, b.len())?;
    let (mut se, mut weight) = (0.0f64, 0.0f64);
    for (p, &m) in mask.iter().enumerate() {
        let m = m as f64;
        weight += m;
        se += m * (0..3).map(|c| (a[3 * p + c] as f64 - b[3 * p + c] as f64).powi(2)).sum::<f64>();
    }
    if weight <= 0.0 {
        return Err(MetricsError::Empty { what: "mask" });
    }
    Ok(ImageMetrics {
        psnr: psnr_from_mse(se / (3.0 * weight)),
        ssim: ssim(width, height, 3, &white_composite(a, mask), &white_composite(b, mask))?,
    })
}

/// `img * mask + (1 - mask)`: an RGB-interleaved image over white outside the mask (one
/// mask value per pixel), as the masked protocol's SSIM and LPIPS see it.
pub(crate) fn white_composite(img: &[f32], mask: &[f32]) -> Vec<f32> {
    img.iter().enumerate().map(|(i, &v)| v * mask[i / 3] + (1.0 - mask[i / 3])).collect()
}

/// SciPy's `_gaussian_kernel1d`: `exp(-x^2 / (2 sigma^2))` for `x = -radius..=radius`,
/// normalised to sum 1.
fn gaussian_kernel(sigma: f64, radius: usize) -> Vec<f64> {
    let r = radius as i64;
    let k: Vec<f64> = (-r..=r).map(|x| (-0.5 / (sigma * sigma) * (x * x) as f64).exp()).collect();
    let sum: f64 = k.iter().sum();
    k.into_iter().map(|v| v / sum).collect()
}

/// SciPy's `mode='reflect'` index: `d c b a | a b c d | d c b a` (period `2n`).
fn reflect(i: i64, n: usize) -> usize {
    let n = n as i64;
    let m = i.rem_euclid(2 * n);
    (if m < n { m } else { 2 * n - 1 - m }) as usize
}

/// Separable correlation of a `w x h` single-channel image with the symmetric 1-D
/// `kernel`, along columns (axis 0) then rows (axis 1), reflect-extended.
fn filter_reflect(w: usize, h: usize, img: Vec<f64>, kernel: &[f64]) -> Vec<f64> {
    let r = (kernel.len() / 2) as i64;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] =
                kernel.iter().enumerate().map(|(k, &wk)| wk * img[reflect(y as i64 + k as i64 - r, h) * w + x]).sum();
        }
    }
    let mut out = img;
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] =
                kernel.iter().enumerate().map(|(k, &wk)| wk * tmp[y * w + reflect(x as i64 + k as i64 - r, w)]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32, c: usize) -> Vec<f32> {
        (0..(w * h) as usize * c).map(|i| ((i * 37 % 101) as f32) / 100.0).collect()
    }

    #[test]
    fn identical_images_have_ssim_one_and_capped_psnr() {
        let a = ramp(16, 13, 3);
        let m = image_metrics(16, 13, &a, &a).unwrap();
        assert!((m.ssim - 1.0).abs() < 1e-12, "{}", m.ssim);
        assert_eq!(m.psnr, 100.0);
    }

    #[test]
    fn psnr_of_a_known_mse() {
        // Every value off by 0.1: MSE 0.01, PSNR 20 dB.
        let a = vec![0.5f32; 30];
        let b = vec![0.6f32; 30];
        assert!((mse(&a, &b).unwrap() - 0.01).abs() < 1e-8);
        assert!((psnr(&a, &b).unwrap() - 20.0).abs() < 1e-5);
        assert!((psnr_from_mse(1e-3) - 30.0).abs() < 1e-12);
    }

    #[test]
    fn reflect_matches_scipy() {
        // n = 4: ... 1 0 | 0 1 2 3 | 3 2 ...
        let got: Vec<usize> = (-5..9).map(|i| reflect(i, 4)).collect();
        assert_eq!(got, [3, 3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0, 0]);
    }

    #[test]
    fn kernel_is_normalised_11_taps() {
        let k = gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS);
        assert_eq!(k.len(), 11);
        assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!(k[5] > k[4] && (k[4] - k[6]).abs() < 1e-18);
    }

    #[test]
    fn constant_offset_lowers_ssim_and_sizes_are_checked() {
        let a = ramp(12, 12, 1);
        let b: Vec<f32> = a.iter().map(|v| v * 0.5).collect();
        let s = ssim(12, 12, 1, &a, &b).unwrap();
        assert!(s < 0.99 && s > 0.0, "{s}");
        assert!(matches!(ssim(10, 12, 1, &a[..120], &b[..120]), Err(MetricsError::ImageTooSmall { .. })));
        assert!(matches!(ssim(12, 12, 1, &a, &b[1..]), Err(MetricsError::SizeMismatch { .. })));
    }

    #[test]
    fn masked_metrics_ignore_pixels_outside_the_mask() {
        let (w, h) = (12u32, 12u32);
        let a = ramp(w, h, 3);
        let mut b = a.clone();
        let mask: Vec<f32> = (0..144).map(|p| if p % 12 < 6 { 1.0 } else { 0.0 }).collect();
        for p in 0..144 {
            if mask[p] == 0.0 {
                b[3 * p..3 * p + 3].fill(0.0); // garbage outside the mask
            } else {
                b[3 * p] += 0.1; // red off by 0.1 inside: MSE 0.01 / 3
            }
        }
        let m = masked_image_metrics(w, h, &a, &b, &mask).unwrap();
        assert!((m.psnr - psnr_from_mse(0.01 / 3.0)).abs() < 1e-5, "{}", m.psnr);
        let unmasked = image_metrics(w, h, &a, &b).unwrap();
        assert!(m.psnr > unmasked.psnr && m.ssim > unmasked.ssim);
        assert!(masked_image_metrics(w, h, &a, &b, &[0.0; 144]).is_err());
    }
}
