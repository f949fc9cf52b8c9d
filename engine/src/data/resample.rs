//! Image resampling, the one place the data room changes an image's resolution: the
//! downsampling of `images/` on load when a scene has no `images_N` folder for the
//! requested factor (LLFF, COLMAP, nerfstudio), applied alike to pictures, alpha, masks
//! and depth maps.
//!
//! * Pictures, alpha and masks: area averaging ([`resize_area`]), each output pixel the
//!   mean of the input area it covers (partial pixels weighted by their overlap), what
//!   a camera with bigger pixels would have recorded.
//! * Depth maps: nearest neighbour at the output pixel centre ([`resize_nearest`]), so
//!   no depth is invented between a foreground and a background surface (as nerfstudio
//!   resizes depth, `cv2.INTER_NEAREST`).
//!
//! Invariants: the output pixel `(x, y)` covers the input rectangle
//! `[x w / w2, (x + 1) w / w2) x [y h / h2, (y + 1) h / h2)` (pixel-corner origin), the
//! mapping [`super::Camera::resized`] applies to the intrinsics; values are interleaved,
//! `channels` per pixel, row-major; a constant image stays constant.

/// The size of an image downsampled by `factor`: `round(w / factor)`, at least 1 pixel.
pub fn downscaled_size(width: u32, height: u32, factor: u32) -> (u32, u32) {
    let f = factor.max(1) as f64;
    let s = |n: u32| ((n as f64 / f).round() as u32).max(1);
    (s(width), s(height))
}

/// Per output index along one axis: the input indices it covers and their weights
/// (summing to 1).
fn area_weights(n_in: u32, n_out: u32) -> Vec<Vec<(usize, f32)>> {
    let scale = n_in as f64 / n_out as f64;
    (0..n_out)
        .map(|o| {
            let (lo, hi) = (o as f64 * scale, (o + 1) as f64 * scale);
            let mut taps = Vec::new();
            let mut i = lo.floor() as usize;
            while (i as f64) < hi && i < n_in as usize {
                let overlap = (hi.min(i as f64 + 1.0) - lo.max(i as f64)).max(0.0);
                if overlap > 0.0 {
                    taps.push((i, (overlap / scale) as f32));
                }
                i += 1;
            }
            taps
        })
        .collect()
}

/// Area-averaging resize of a `w x h` image with `channels` interleaved values per pixel
/// to `w2 x h2` (separable: rows, then columns).
pub fn resize_area(values: &[f32], channels: usize, (w, h): (u32, u32), (w2, h2): (u32, u32)) -> Vec<f32> {
    assert_eq!(values.len(), channels * w as usize * h as usize, "image data length does not match its size");
    let (wx, wy) = (area_weights(w, w2), area_weights(h, h2));
    // Horizontal pass: h rows of w2 pixels.
    let mut rows = vec![0.0f32; channels * w2 as usize * h as usize];
    for y in 0..h as usize {
        for (x2, taps) in wx.iter().enumerate() {
            let out = &mut rows[channels * (y * w2 as usize + x2)..][..channels];
            for &(x, wt) in taps {
                let src = &values[channels * (y * w as usize + x)..][..channels];
                for c in 0..channels {
                    out[c] += wt * src[c];
                }
            }
        }
    }
    let mut result = vec![0.0f32; channels * w2 as usize * h2 as usize];
    for (y2, taps) in wy.iter().enumerate() {
        for &(y, wt) in taps {
            let src = &rows[channels * y * w2 as usize..][..channels * w2 as usize];
            let out = &mut result[channels * y2 * w2 as usize..][..channels * w2 as usize];
            for (o, s) in out.iter_mut().zip(src) {
                *o += wt * s;
            }
        }
    }
    result
}

/// Nearest-neighbour resize (the input pixel under each output pixel's centre).
pub fn resize_nearest(values: &[f32], channels: usize, (w, h): (u32, u32), (w2, h2): (u32, u32)) -> Vec<f32> {
    assert_eq!(values.len(), channels * w as usize * h as usize, "image data length does not match its size");
    let src = |o: u32, n_out: u32, n_in: u32| (((o as f64 + 0.5) * n_in as f64 / n_out as f64) as usize).min(n_in as usize - 1);
    let mut out = Vec::with_capacity(channels * w2 as usize * h2 as usize);
    for y2 in 0..h2 {
        let y = src(y2, h2, h);
        for x2 in 0..w2 {
            let x = src(x2, w2, w);
            out.extend_from_slice(&values[channels * (y * w as usize + x)..][..channels]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_and_nearest_of_known_images() {
        assert_eq!(downscaled_size(4032, 3024, 8), (504, 378));
        assert_eq!(downscaled_size(5, 3, 2), (3, 2));
        // 4x2, one channel, halved: block means.
        let img = [1.0, 3.0, 5.0, 7.0, 2.0, 4.0, 6.0, 8.0];
        assert_eq!(resize_area(&img, 1, (4, 2), (2, 1)), vec![2.5, 6.5]);
        assert_eq!(resize_nearest(&img, 1, (4, 2), (2, 1)), vec![4.0, 8.0]);
        // 3 -> 2 pixels: each output covers 1.5 input pixels.
        let row = [0.0, 3.0, 6.0];
        let out = resize_area(&row, 1, (3, 1), (2, 1));
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[1] - 5.0).abs() < 1e-6, "{out:?}");
        // A constant RGB image stays constant.
        let rgb = vec![0.25f32; 3 * 7 * 5];
        assert!(resize_area(&rgb, 3, (7, 5), (3, 2)).iter().all(|v| (v - 0.25).abs() < 1e-6));
    }
}
