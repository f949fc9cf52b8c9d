//! The Canny edge detector (Canny 1986), general purpose: training images (on their
//! luminance) for the edge masks, and normalized depth maps for the depth-boundary
//! error (iBims-1).
//!
//! Steps: Gaussian blur (separable, radius `ceil(3 sigma)`, borders replicated), Sobel
//! gradients, non-maximum suppression against the two neighbours along the gradient
//! direction quantized to multiples of 45 degrees (as OpenCV), then a double threshold
//! with hysteresis: weak pixels survive only when 8-connected, through weak pixels, to
//! a strong one. Thresholds follow MATLAB's `edge(..., 'canny')` convention (below).
//!
//! Invariant: thresholds are on the gradient magnitude **relative to the image's
//! maximum gradient magnitude** (MATLAB's convention), so they lie in `[0, 1]` and do
//! not depend on the image's scale: `canny(k * img) == canny(img)` for any `k > 0`. An
//! image without any gradient (flat) has no edges. Output edges are one pixel thick.

use std::collections::VecDeque;

use super::CannyParams;

/// Rec. 601 luma of an RGB image (`3` floats per pixel, as stored: sRGB-encoded),
/// `0.299 R + 0.587 G + 0.114 B` per pixel: the grey image Canny runs on (the same
/// weights as OpenCV's `cvtColor` and MATLAB's `rgb2gray`).
pub fn luma(rgb: &[f32]) -> Vec<f32> {
    rgb.chunks_exact(3).map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2]).collect()
}

/// Canny edges of the grey image `img` (`width * height` values, row-major; any
/// scale: `[0, 1]` grey, normalized depth, ...). Returns one flag per pixel, `true` on
/// edge pixels.
///
/// `params.sigma` is the Gaussian's standard deviation in pixels (`0` skips the blur);
/// `params.low` and `params.high` are fractions of the image's largest gradient
/// magnitude (after blurring), `0 <= low <= high <= 1`: pixels at or above `high` are
/// edges, pixels at or above `low` are edges when connected to such a pixel. (A `low`
/// above `high` is treated as equal to `high`.) For iBims-1's depth-boundary error
/// use `sigma = sqrt(2)`, `low = 0.1`, `high = 0.2` on depth normalized to `[0, 1]`.
///
/// Panics if `img.len() != width * height` (a caller bug, not a data error).
pub fn canny(img: &[f32], width: u32, height: u32, params: &CannyParams) -> Vec<bool> {
    let (w, h) = (width as usize, height as usize);
    assert_eq!(img.len(), w * h, "canny: {} values for a {width}x{height} image", img.len());
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let blurred = gaussian_blur(img, w, h, params.sigma);
    let (gx, gy) = sobel(&blurred, w, h);
    let mag: Vec<f32> = gx.iter().zip(&gy).map(|(x, y)| x.hypot(*y)).collect();
    let max = mag.iter().copied().filter(|m| m.is_finite()).fold(0.0f32, f32::max);
    // No gradient at all (or only rounding noise of a flat image): no edges.
    let scale = img.iter().copied().filter(|v| v.is_finite()).fold(0.0f32, |a, v| a.max(v.abs()));
    if max <= 1e-6 * scale.max(f32::MIN_POSITIVE) || max <= f32::MIN_POSITIVE {
        return vec![false; w * h];
    }
    let high = params.high * max;
    let low = params.low.min(params.high) * max;

    // Non-maximum suppression: keep a pixel when its magnitude is a maximum among its
    // two neighbours along the gradient direction, quantized to 0, 45, 90 or 135
    // degrees. Ties (a step edge exactly between two pixels gives them equal
    // magnitudes, up to rounding) keep only the pixel whose neighbour at `-d` is lower,
    // so edges stay one pixel thick; magnitudes within `tie` count as equal, which
    // keeps the choice independent of rounding (and of the image's scale).
    let tie = 1e-4 * max;
    let mut thin = vec![0.0f32; w * h];
    let tan22 = (std::f32::consts::PI / 8.0).tan();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let m = mag[i];
            if !(m >= low && m > 0.0) {
                continue;
            }
            let (ax, ay) = (gx[i].abs(), gy[i].abs());
            // Neighbour offset (dx, dy) along the gradient, up to sign.
            let (dx, dy): (isize, isize) = if ay <= tan22 * ax {
                (1, 0)
            } else if ax <= tan22 * ay {
                (0, 1)
            } else if (gx[i] > 0.0) == (gy[i] > 0.0) {
                (1, 1)
            } else {
                (1, -1)
            };
            let get = |dx: isize, dy: isize| {
                let (nx, ny) = (x as isize + dx, y as isize + dy);
                if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize { 0.0 } else { mag[ny as usize * w + nx as usize] }
            };
            if m >= get(dx, dy) - tie && m > get(-dx, -dy) + tie {
                thin[i] = m;
            }
        }
    }

    // Hysteresis: flood from strong pixels through weak ones (8-connected).
    let mut edge = vec![false; w * h];
    let mut queue = VecDeque::new();
    for (i, &m) in thin.iter().enumerate() {
        if m >= high && m > 0.0 {
            edge[i] = true;
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        let (x, y) = ((i % w) as isize, (i / w) as isize);
        for dy in -1..=1isize {
            for dx in -1..=1isize {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if !edge[j] && thin[j] >= low && thin[j] > 0.0 {
                    edge[j] = true;
                    queue.push_back(j);
                }
            }
        }
    }
    edge
}

/// Normalized 1-D Gaussian of standard deviation `sigma`, radius `ceil(3 sigma)`.
fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as i32;
    let k: Vec<f32> = (-r..=r).map(|i| (-((i * i) as f32) / (2.0 * sigma * sigma)).exp()).collect();
    let sum: f32 = k.iter().sum();
    k.into_iter().map(|v| v / sum).collect()
}

/// Separable Gaussian blur with replicated borders; `sigma <= 0` (or NaN) returns a copy.
pub fn gaussian_blur(img: &[f32], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    if sigma.is_nan() || sigma <= 0.0 {
        return img.to_vec();
    }
    let k = gaussian_kernel(sigma);
    let r = (k.len() / 2) as isize;
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let mut tmp = vec![0.0f32; w * h];
    for y in 0..h {
        let row = &img[y * w..(y + 1) * w];
        for x in 0..w {
            tmp[y * w + x] = k.iter().enumerate().map(|(j, kv)| kv * row[clamp(x as isize + j as isize - r, w)]).sum();
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = k.iter().enumerate().map(|(j, kv)| kv * tmp[clamp(y as isize + j as isize - r, h) * w + x]).sum();
        }
    }
    out
}

/// Sobel derivatives (`x` right, `y` down), divided by 8 so that a unit ramp gives 1;
/// borders replicated.
fn sobel(img: &[f32], w: usize, h: usize) -> (Vec<f32>, Vec<f32>) {
    let px = |x: isize, y: isize| img[y.clamp(0, h as isize - 1) as usize * w + x.clamp(0, w as isize - 1) as usize];
    let mut gx = vec![0.0f32; w * h];
    let mut gy = vec![0.0f32; w * h];
    for y in 0..h as isize {
        for x in 0..w as isize {
            let i = y as usize * w + x as usize;
            gx[i] = (px(x + 1, y - 1) + 2.0 * px(x + 1, y) + px(x + 1, y + 1)
                - px(x - 1, y - 1)
                - 2.0 * px(x - 1, y)
                - px(x - 1, y + 1))
                / 8.0;
            gy[i] = (px(x - 1, y + 1) + 2.0 * px(x, y + 1) + px(x + 1, y + 1)
                - px(x - 1, y - 1)
                - 2.0 * px(x, y - 1)
                - px(x + 1, y - 1))
                / 8.0;
        }
    }
    (gx, gy)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(sigma: f32, low: f32, high: f32) -> CannyParams {
        CannyParams { sigma, low, high }
    }

    /// A `w x h` image, `fg` where `inside(x, y)` (pixel centres), `bg` elsewhere.
    fn shape(w: u32, h: u32, fg: f32, bg: f32, inside: impl Fn(f32, f32) -> bool) -> Vec<f32> {
        (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| if inside(x as f32 + 0.5, y as f32 + 0.5) { fg } else { bg }).collect()
    }

    /// `true` when a 4-connected flood fill of non-edge pixels from `(sx, sy)` stays off
    /// the image border, i.e. the edges enclose the start.
    fn enclosed(edge: &[bool], w: usize, h: usize, sx: usize, sy: usize) -> bool {
        let mut seen = vec![false; w * h];
        let mut stack = vec![(sx, sy)];
        while let Some((x, y)) = stack.pop() {
            let i = y * w + x;
            if seen[i] || edge[i] {
                continue;
            }
            seen[i] = true;
            if x == 0 || y == 0 || x == w - 1 || y == h - 1 {
                return false;
            }
            stack.extend([(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)]);
        }
        true
    }

    #[test]
    fn disc_edges_are_on_the_boundary_thin_and_closed() {
        let (w, h) = (64u32, 64u32);
        let (cx, cy, r) = (32.0f32, 31.0f32, 17.3f32);
        let img = shape(w, h, 0.9, 0.1, |x, y| (x - cx).hypot(y - cy) < r);
        let edge = canny(&img, w, h, &params(1.4, 0.1, 0.2));
        let n = edge.iter().filter(|&&e| e).count();
        assert!(n > 0);
        for (i, _) in edge.iter().enumerate().filter(|(_, e)| **e) {
            let (x, y) = ((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5);
            let d = ((x - cx).hypot(y - cy) - r).abs();
            assert!(d < 1.0, "edge pixel ({x}, {y}) is {d} px from the circle");
        }
        // Thin: no more pixels than a 4-connected digital circle (8 r) and no fewer than
        // an 8-connected one (4 sqrt(2) r), and no 2x2 block of edges.
        assert!((n as f32) <= 8.0 * r && (n as f32) >= 0.95 * 4.0 * 2f32.sqrt() * r, "{n} edge pixels for a radius of {r}");
        for y in 0..63 {
            for x in 0..63 {
                let block = [edge[y * 64 + x], edge[y * 64 + x + 1], edge[(y + 1) * 64 + x], edge[(y + 1) * 64 + x + 1]];
                assert!(!block.iter().all(|&e| e), "2x2 block of edges at ({x}, {y})");
            }
        }
        assert!(enclosed(&edge, 64, 64, 32, 31), "the disc's edge is not closed");
    }

    #[test]
    fn square_edges_are_one_pixel_wide_and_scale_free() {
        let (w, h) = (48u32, 40u32);
        let img = shape(w, h, 1.0, 0.0, |x, y| (10.0..30.0).contains(&x) && (8.0..28.0).contains(&y));
        let p = params(1.4, 0.1, 0.2);
        let edge = canny(&img, w, h, &p);
        // Every row through the middle of the square crosses exactly two edge pixels,
        // next to x = 10 and x = 30.
        for y in 12..24 {
            let xs: Vec<usize> = (0..48).filter(|&x| edge[y * 48 + x]).collect();
            assert_eq!(xs.len(), 2, "row {y}: {xs:?}");
            assert!((9..=10).contains(&xs[0]) && (29..=30).contains(&xs[1]), "row {y}: {xs:?}");
        }
        assert!(enclosed(&edge, 48, 40, 20, 18));
        // Relative thresholds: scaling the image changes nothing.
        let scaled: Vec<f32> = img.iter().map(|v| 40.0 * v + 3.0).collect();
        assert_eq!(canny(&scaled, w, h, &p), edge);
    }

    #[test]
    fn hysteresis_keeps_connected_weak_edges_and_drops_isolated_ones() {
        // 60x40, no blur. A strong vertical step of 1.0 at x = 30 (all rows); a weak
        // horizontal step of 0.15 along y = 20 for x >= 30, which starts on the strong
        // edge; an isolated weak vertical step of 0.15 at x = 12, 18 px from anything
        // strong. Relative magnitudes: strong >= 0.87, weak about 0.13.
        let (w, h) = (60u32, 40u32);
        let mut img = vec![0.0f32; 60 * 40];
        for y in 0..40 {
            for x in 0..60 {
                let v = &mut img[y * 60 + x];
                if x >= 30 {
                    *v += 1.0;
                }
                if x >= 30 && y >= 20 {
                    *v += 0.15;
                }
                if x < 12 {
                    *v += 0.15;
                }
            }
        }
        let strong = |e: &[bool]| (0..40).all(|y| e[y * 60 + 29] || e[y * 60 + 30]);
        let connected = |e: &[bool]| (32..58).all(|x| e[19 * 60 + x] || e[20 * 60 + x]);
        let isolated = |e: &[bool]| (0..40).filter(|y| e[y * 60 + 11] || e[y * 60 + 12]).count();
        let e = canny(&img, w, h, &params(0.0, 0.1, 0.5));
        assert!(strong(&e), "strong edge kept");
        assert!(connected(&e), "weak edge connected to the strong one kept");
        assert_eq!(isolated(&e), 0, "isolated weak edge dropped");
        assert!(e.iter().enumerate().all(|(i, &v)| !v || [29, 30, 11, 12].contains(&(i % 60)) || [19, 20].contains(&(i / 60))), "no other edges");
        // Lowering `high` under the weak magnitude makes the isolated one strong.
        let e = canny(&img, w, h, &params(0.0, 0.1, 0.12));
        assert_eq!(isolated(&e), 40, "weak edge above `high` kept");
        // Raising `low` over the weak magnitude drops the connected weak edge too.
        let e = canny(&img, w, h, &params(0.0, 0.2, 0.5));
        assert!(strong(&e) && (32..58).all(|x| !e[19 * 60 + x] && !e[20 * 60 + x]), "weak edge under `low` dropped");
    }

    #[test]
    fn flat_images_have_no_edges() {
        for v in [0.0f32, 0.5, 1000.0] {
            let img = vec![v; 32 * 20];
            assert!(canny(&img, 32, 20, &params(1.4, 0.1, 0.2)).iter().all(|&e| !e), "flat {v}");
        }
        assert!(canny(&[], 0, 0, &params(1.0, 0.1, 0.2)).is_empty());
    }

    #[test]
    fn luma_uses_rec601_weights() {
        let g = luma(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]);
        let expect = [0.299, 0.587, 0.114, 1.0];
        for (a, b) in g.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{g:?}");
        }
    }
}
