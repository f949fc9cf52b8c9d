//! Image files: RGB(A) PNG/JPEG pictures, grayscale masks, and OpenEXR depth/normal maps.
//!
//! Invariants: an [`ImageRgb`] holds `3 * width * height` floats, row-major from the
//! top-left pixel, values as stored in the file scaled to `[0, 1]` (no colour-space
//! conversion). RGBA files are composited over a caller-given background,
//! `rgb * a + bg * (1 - a)` (straight alpha, as NeRF-synthetic). Depth EXRs hold one
//! `f32` channel `Y`; normal EXRs hold `R`, `G`, `B` = world-space `x`, `y`, `z`. Every
//! error names the file.

use std::path::{Path, PathBuf};

use exr::prelude::{self as exrp, FlatSamples, WritableImage};
use image::ImageDecoder;

use super::DataError;
use super::resample::{downscaled_size, resize_area};

/// An RGB image with `f32` channels, row-major, 3 floats per pixel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageRgb {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

/// Size and whether an image file has an alpha channel, read from its header only.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageInfo {
    pub width: u32,
    pub height: u32,
    pub has_alpha: bool,
}

impl ImageRgb {
    /// A black image.
    pub fn new(width: u32, height: u32) -> ImageRgb {
        ImageRgb {
            width,
            height,
            data: vec![0.0; 3 * width as usize * height as usize],
        }
    }

    /// `true` when the image holds no pixels (views loaded without images).
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    fn index(&self, x: u32, y: u32) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside {}x{}",
            self.width,
            self.height
        );
        3 * (y as usize * self.width as usize + x as usize)
    }

    /// Pixel `(x, y)`; panics outside the image.
    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        let i = self.index(x, y);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Sets pixel `(x, y)`; panics outside the image.
    pub fn set(&mut self, x: u32, y: u32, rgb: [f32; 3]) {
        let i = self.index(x, y);
        self.data[i..i + 3].copy_from_slice(&rgb);
    }

    /// Loads a PNG or JPEG. RGBA images are composited over `background`; the alpha
    /// channel is returned too (`None` when the file has none).
    pub fn load(
        path: impl AsRef<Path>,
        background: [f32; 3],
    ) -> Result<(ImageRgb, Option<Vec<f32>>), DataError> {
        let path = path.as_ref();
        let img = decode(path)?;
        let has_alpha = img.color().has_alpha();
        let rgba = img.into_rgba32f();
        let (width, height) = rgba.dimensions();
        let mut data = Vec::with_capacity(3 * width as usize * height as usize);
        let mut alpha = has_alpha.then(|| Vec::with_capacity(width as usize * height as usize));
        for p in rgba.pixels() {
            let a = if has_alpha { p[3].clamp(0.0, 1.0) } else { 1.0 };
            for c in 0..3 {
                data.push(p[c] * a + background[c] * (1.0 - a));
            }
            if let Some(alpha) = alpha.as_mut() {
                alpha.push(a);
            }
        }
        Ok((
            ImageRgb {
                width,
                height,
                data,
            },
            alpha,
        ))
    }

    /// Writes an 8-bit RGB PNG (values clamped to `[0, 1]` and rounded).
    pub fn save_png(&self, path: impl AsRef<Path>) -> Result<(), DataError> {
        let path = path.as_ref();
        let bytes: Vec<u8> = self
            .data
            .iter()
            .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        let buf = image::RgbImage::from_raw(self.width, self.height, bytes)
            .ok_or_else(|| DataError::invalid(path, "image data length does not match its size"))?;
        // Encoded in memory, then written: `save_with_format` writes through a
        // BufWriter whose final flush error is dropped, so a full disk left a cut PNG
        // and reported success.
        let mut png = Vec::new();
        buf.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|source| DataError::Image {
                path: path.to_path_buf(),
                source,
            })?;
        std::fs::write(path, png).map_err(|e| DataError::io(path, e))
    }
}

fn decode(path: &Path) -> Result<image::DynamicImage, DataError> {
    reader(path)?.decode().map_err(|source| DataError::Image {
        path: path.to_path_buf(),
        source,
    })
}

fn reader(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>, DataError> {
    image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| DataError::io(path, e))
}

/// Reads only the header of an image file: size and alpha.
pub fn image_info(path: impl AsRef<Path>) -> Result<ImageInfo, DataError> {
    let path = path.as_ref();
    let decoder = reader(path)?
        .into_decoder()
        .map_err(|source| DataError::Image {
            path: path.to_path_buf(),
            source,
        })?;
    let (width, height) = decoder.dimensions();
    Ok(ImageInfo {
        width,
        height,
        has_alpha: decoder.color_type().has_alpha(),
    })
}

/// Loads a mask image (any colour type) as one value in `[0, 1]` per pixel: the mean
/// of the colour channels (alpha ignored). Returns `(width, height, values)`.
pub fn load_mask(path: impl AsRef<Path>) -> Result<(u32, u32, Vec<f32>), DataError> {
    let path = path.as_ref();
    let rgb = decode(path)?.into_rgb32f();
    let (w, h) = rgb.dimensions();
    Ok((
        w,
        h,
        rgb.pixels().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect(),
    ))
}

/// Loads a grey image's raw values (16-bit PNGs as stored, 8-bit ones widened to 16
/// bits as the `image` crate does, `v * 257`) as `f32`, for sensor depth maps stored in
/// integer units (millimetres, nerfstudio's default). Returns `(width, height, values)`.
pub fn load_grey16(path: impl AsRef<Path>) -> Result<(u32, u32, Vec<f32>), DataError> {
    let path = path.as_ref();
    let grey = decode(path)?.into_luma16();
    let (w, h) = grey.dimensions();
    Ok((w, h, grey.pixels().map(|p| f32::from(p[0])).collect()))
}

fn exr_error(path: &Path, message: impl std::fmt::Display) -> DataError {
    DataError::Exr {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// The most decoded sample memory an EXR may ask for, as for the `image` crate's default
/// limit on PNG/JPEG decoding: 512 MiB (a 8192 x 8192 four-channel `f32` map needs 1 GiB
/// and is refused; a 4096 x 4096 one fits with room).
const EXR_MAX_DECODED_BYTES: u128 = 512 << 20;

/// Refuses, from the header alone, an EXR whose layers would decode to more than
/// [`EXR_MAX_DECODED_BYTES`]: the `exr` crate allocates what a (possibly corrupt) data
/// window declares before reading a pixel, and a failed allocation aborts the process
/// instead of returning an error.
fn check_exr_size(path: &Path) -> Result<(), DataError> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| exr_error(path, e))?;
    for header in &meta.headers {
        let (w, h) = (header.layer_size.width() as u128, header.layer_size.height() as u128);
        let channels = header.channels.list.len() as u128;
        // Every sample is converted to `f32`, whatever its stored type.
        let bytes = w * h * channels * 4;
        if bytes > EXR_MAX_DECODED_BYTES {
            return Err(exr_error(
                path,
                format!(
                    "its header declares a {w}x{h} layer with {channels} channel(s), {} MiB decoded, over the {} MiB limit; the file is corrupt or not a per-view map (write one with save_depth_exr / save_normal_exr)",
                    bytes >> 20,
                    EXR_MAX_DECODED_BYTES >> 20
                ),
            ));
        }
    }
    Ok(())
}

/// Reads the named channels (first name found in each group of alternatives) of the
/// first layer of an EXR file, as `f32`, row-major.
fn read_exr_channels(
    path: &Path,
    wanted: &[&[&str]],
) -> Result<(u32, u32, Vec<Vec<f32>>), DataError> {
    if !path.is_file() {
        return Err(DataError::NotFound {
            path: path.to_path_buf(),
            what: "EXR file",
        });
    }
    check_exr_size(path)?;
    let image = exrp::read_first_flat_layer_from_file(path).map_err(|e| exr_error(path, e))?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let channels = &layer.channel_data.list;
    let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
    let mut out = Vec::with_capacity(wanted.len());
    for alternatives in wanted {
        let channel = channels
            .iter()
            .find(|c| alternatives.iter().any(|a| c.name.eq(a)))
            // A single-channel file is a depth map whatever its channel is called.
            .or_else(|| (wanted.len() == 1 && channels.len() == 1).then(|| &channels[0]))
            .ok_or_else(|| {
                exr_error(
                    path,
                    format!("expected channel {} but the file has {names:?}; write it with save_depth_exr / save_normal_exr", alternatives.join(" or ")),
                )
            })?;
        let values: Vec<f32> = match &channel.sample_data {
            FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
        };
        out.push(values);
    }
    Ok((w as u32, h as u32, out))
}

/// Loads a ground-truth depth map: single channel `Y` (any single channel is accepted),
/// ray distance per pixel, `0` where nothing was hit. Returns `(width, height, depth)`.
pub fn load_depth_exr(path: impl AsRef<Path>) -> Result<(u32, u32, Vec<f32>), DataError> {
    let path = path.as_ref();
    let (w, h, mut channels) = read_exr_channels(path, &[&["Y", "Z", "depth"]])?;
    Ok((w, h, channels.remove(0)))
}

/// Loads a ground-truth normal map: channels `R`, `G`, `B` (or `X`, `Y`, `Z`) holding the
/// world-space normal's `x`, `y`, `z`; `(0, 0, 0)` where nothing was hit.
pub fn load_normal_exr(path: impl AsRef<Path>) -> Result<(u32, u32, Vec<[f32; 3]>), DataError> {
    let path = path.as_ref();
    let (w, h, c) = read_exr_channels(path, &[&["R", "X"], &["G", "Y"], &["B", "Z"]])?;
    let normals = c[0]
        .iter()
        .zip(&c[1])
        .zip(&c[2])
        .map(|((&x, &y), &z)| [x, y, z])
        .collect();
    Ok((w, h, normals))
}

fn check_len(path: &Path, width: u32, height: u32, len: usize) -> Result<(), DataError> {
    if len != width as usize * height as usize {
        return Err(DataError::invalid(
            path,
            format!("{len} values given for a {width}x{height} map; pass exactly one per pixel"),
        ));
    }
    Ok(())
}

/// Writes a depth map as a single-channel (`Y`) `f32` EXR.
pub fn save_depth_exr(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    depth: &[f32],
) -> Result<(), DataError> {
    let path = path.as_ref();
    check_len(path, width, height, depth.len())?;
    let w = width as usize;
    let channels = exrp::SpecificChannels::build()
        .with_channel("Y")
        .with_pixel_fn(|p: exrp::Vec2<usize>| (depth[p.y() * w + p.x()],));
    exrp::Image::from_channels((w, height as usize), channels)
        .write()
        .to_file(path)
        .map_err(|e| exr_error(path, e))
}

/// Writes a normal map as an `f32` EXR with channels `R`, `G`, `B` = `x`, `y`, `z`.
pub fn save_normal_exr(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    normals: &[[f32; 3]],
) -> Result<(), DataError> {
    let path = path.as_ref();
    check_len(path, width, height, normals.len())?;
    let w = width as usize;
    let channels = exrp::SpecificChannels::rgb(|p: exrp::Vec2<usize>| {
        let n = normals[p.y() * w + p.x()];
        (n[0], n[1], n[2])
    });
    exrp::Image::from_channels((w, height as usize), channels)
        .write()
        .to_file(path)
        .map_err(|e| exr_error(path, e))
}

/// Image files (`png`, `jpg`, `jpeg`, any case) directly inside `dir`, sorted by name.
pub(crate) fn list_images(dir: &Path, what: &'static str) -> Result<Vec<PathBuf>, DataError> {
    if !dir.is_dir() {
        return Err(DataError::NotFound {
            path: dir.to_path_buf(),
            what,
        });
    }
    let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| DataError::io(dir, e))?.path();
        let is_image = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| ["png", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str()));
        if is_image && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// The file stem of `path` as a string (the view name).
pub(crate) fn file_stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Enforces the one-size-per-scene invariant: remembers the first file's size and
/// rejects any later file (image, mask or ground-truth map) of another size.
#[derive(Default)]
pub(crate) struct SizeGuard {
    first: Option<(PathBuf, (u32, u32))>,
}

impl SizeGuard {
    pub(crate) fn check(&mut self, path: &Path, size: (u32, u32)) -> Result<(), DataError> {
        match &self.first {
            None => {
                self.first = Some((path.to_path_buf(), size));
                Ok(())
            }
            Some((reference, expected)) if *expected != size => Err(DataError::SizeMismatch {
                path: path.to_path_buf(),
                reference: reference.clone(),
                got: size,
                expected: *expected,
            }),
            Some(_) => Ok(()),
        }
    }
}

/// One view's picture as the loaders need it.
pub(crate) struct ViewImage {
    /// Empty unless pixels were loaded.
    pub image: ImageRgb,
    /// Alpha channel, when pixels were loaded and the file has one.
    pub alpha: Option<Vec<f32>>,
    pub info: ImageInfo,
}

/// Loads `path` (or, with `load_pixels == false`, only its header) and checks its size
/// with `guard`.
pub(crate) fn read_view_image(
    path: &Path,
    load_pixels: bool,
    background: [f32; 3],
    guard: &mut SizeGuard,
) -> Result<ViewImage, DataError> {
    let info = image_info(path)?;
    guard.check(path, (info.width, info.height))?;
    let (image, alpha) = if load_pixels {
        ImageRgb::load(path, background)?
    } else {
        (ImageRgb::default(), None)
    };
    Ok(ViewImage { image, alpha, info })
}

impl ViewImage {
    /// The view of this picture at `path` with `camera`: named by the file stem, its
    /// alpha kept, no mask or ground truth yet.
    pub(crate) fn into_view(self, path: PathBuf, camera: super::Camera) -> super::View {
        super::View {
            name: file_stem(&path),
            path,
            camera,
            image: self.image,
            mask: None,
            alpha: self.alpha,
            depth: None,
            normal: None,
            train_mask: None,
        }
    }
}

/// [`read_view_image`] of a picture downsampled by `factor` on load
/// ([`super::resample`]: area averaging of the colour and the alpha; the size is
/// [`downscaled_size`]); `factor` 1 reads it as it is.
pub(crate) fn read_view_image_downscaled(
    path: &Path,
    factor: u32,
    load_pixels: bool,
    background: [f32; 3],
    guard: &mut SizeGuard,
) -> Result<ViewImage, DataError> {
    if factor <= 1 {
        return read_view_image(path, load_pixels, background, guard);
    }
    let full = image_info(path)?;
    let (w, h) = downscaled_size(full.width, full.height, factor);
    guard.check(path, (w, h))?;
    let info = ImageInfo { width: w, height: h, ..full };
    if !load_pixels {
        return Ok(ViewImage { image: ImageRgb::default(), alpha: None, info });
    }
    let (image, alpha) = ImageRgb::load(path, background)?;
    let from = (image.width, image.height);
    let image = ImageRgb { width: w, height: h, data: resize_area(&image.data, 3, from, (w, h)) };
    let alpha = alpha.map(|a| resize_area(&a, 1, from, (w, h)));
    Ok(ViewImage { image, alpha, info })
}

/// Loads a mask and checks that it matches the size of its image `image_path`.
pub(crate) fn read_view_mask(
    path: &Path,
    image_path: &Path,
    size: (u32, u32),
) -> Result<Vec<f32>, DataError> {
    let (w, h, mask) = load_mask(path)?;
    if (w, h) != size {
        return Err(DataError::SizeMismatch {
            path: path.to_path_buf(),
            reference: image_path.to_path_buf(),
            got: (w, h),
            expected: size,
        });
    }
    Ok(mask)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_and_png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (5u32, 3u32);
        let depth: Vec<f32> = (0..15).map(|i| i as f32 * 0.25).collect();
        let normals: Vec<[f32; 3]> = (0..15).map(|i| [i as f32, -1.0, 0.5]).collect();
        let dp = dir.path().join("d.exr");
        let np = dir.path().join("n.exr");
        save_depth_exr(&dp, w, h, &depth).unwrap();
        save_normal_exr(&np, w, h, &normals).unwrap();
        assert_eq!(load_depth_exr(&dp).unwrap(), (w, h, depth));
        assert_eq!(load_normal_exr(&np).unwrap(), (w, h, normals));
        // A depth file is not a normal file: the error names the file and the channels.
        let msg = load_normal_exr(&dp).unwrap_err().to_string();
        assert!(msg.contains("d.exr") && msg.contains("R or X"), "{msg}");

        // A corrupt data window that declares a huge layer is refused from the header,
        // before the `exr` crate tries to allocate it (it aborted the process on 562 TB).
        let bytes = std::fs::read(&dp).unwrap();
        let at = bytes.windows(11).position(|w| w == b"dataWindow\0").unwrap();
        // name, "box2i\0", size (4 bytes), then xMin, yMin, xMax, yMax as i32: the
        // maxima set to 2^20, a 2^20 x 2^20 layer (4 TiB as f32).
        let x_max = at + 11 + 6 + 4 + 8;
        let mut corrupt = bytes;
        corrupt[x_max..x_max + 8].copy_from_slice(&[0, 0, 0x10, 0, 0, 0, 0x10, 0]);
        let bad = dir.path().join("huge.exr");
        std::fs::write(&bad, &corrupt).unwrap();
        let msg = load_depth_exr(&bad).unwrap_err().to_string();
        assert!(msg.contains("huge.exr") && msg.contains("MiB limit"), "{msg}");

        let mut img = ImageRgb::new(w, h);
        img.set(4, 2, [1.0, 0.5, 0.0]);
        let pp = dir.path().join("i.png");
        img.save_png(&pp).unwrap();
        let (back, alpha) = ImageRgb::load(&pp, [0.0; 3]).unwrap();
        assert!(alpha.is_none());
        assert_eq!(back.get(4, 2), [1.0, 128.0 / 255.0, 0.0]);
        assert_eq!(
            image_info(&pp).unwrap(),
            ImageInfo {
                width: w,
                height: h,
                has_alpha: false
            }
        );
    }
}
