//! [`DataError`]: everything that can go wrong while loading a scene.
//!
//! Invariant: every variant names the offending file or directory, says what is wrong
//! with it, and hints at what to do, so a message is useful on its own (no backtrace
//! or context needed). Loaders never panic on user input; they return one of these.

use std::path::PathBuf;

/// A scene, image, or camera file could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A required file or directory does not exist.
    #[error("{what} not found: {path} (check the path and that the dataset is complete)")]
    NotFound { path: PathBuf, what: &'static str },

    /// The directory holds none of the files that identify a known layout.
    #[error(
        "unrecognised scene layout in {path}: expected one of transforms_train.json \
         (blender / NeRF-synthetic), transforms.json (nerfstudio), poses_bounds.npy (LLFF), \
         cameras_sphere.npz (DTU, IDR layout), cameras.npz (DTU, pixelNeRF layout) or a \
         COLMAP model in sparse/0/ or sparse/ (cameras, images, points3D .bin or .txt); \
         point to the scene directory itself"
    )]
    UnknownFormat { path: PathBuf },

    /// The operating system refused to read or write a file.
    #[error("cannot access {path}: {source} (check that it exists and is readable/writable)")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// An image file could not be decoded or encoded.
    #[error("cannot read or write image {path}: {source} (PNG and JPEG are supported)")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },

    /// An OpenEXR file could not be read or written, or lacks the expected channels.
    #[error("bad OpenEXR file {path}: {message}")]
    Exr { path: PathBuf, message: String },

    /// A JSON file does not parse or does not have the expected structure.
    #[error("bad JSON in {path}: {source} (fix or regenerate the file)")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },

    /// A NumPy `.npy` / `.npz` file is malformed or has the wrong dtype or shape.
    #[error("bad NumPy data in {path}: {message}")]
    Npy { path: PathBuf, message: String },

    /// Two files that must have the same pixel size do not.
    #[error(
        "size mismatch: {path} is {}x{} but {reference} is {}x{}; every image, mask and \
         ground-truth map of a scene must have the same size (resize or regenerate it)",
        got.0, got.1, expected.0, expected.1
    )]
    SizeMismatch {
        path: PathBuf,
        reference: PathBuf,
        got: (u32, u32),
        expected: (u32, u32),
    },

    /// A camera pose or intrinsic contains NaN or infinity (or is degenerate).
    #[error(
        "non-finite or degenerate camera in {path}: {what} (fix or regenerate the camera file)"
    )]
    NonFinite { path: PathBuf, what: String },

    /// A camera refers to an image file that does not exist.
    #[error("missing image for {pose}: expected {path} (restore the image or remove the pose)")]
    MissingImage { path: PathBuf, pose: String },

    /// The number of images does not match the number of cameras.
    #[error(
        "{path}: found {images} images for {cameras} cameras; every camera needs exactly one \
         image (check the image folder and the camera file)"
    )]
    CountMismatch {
        path: PathBuf,
        images: usize,
        cameras: usize,
    },

    /// Anything else that makes the data unusable; `message` says what and what to do.
    #[error("invalid scene data in {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl DataError {
    /// Wraps an I/O error with the path it concerns.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.into(),
            source,
        }
    }

    /// Shorthand for [`DataError::Invalid`].
    pub(crate) fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        DataError::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}
