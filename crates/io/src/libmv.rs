//! libmv bundle-adjustment problems (the binary files of Ceres's `libmv_bundle_adjuster`, from
//! Blender's camera tracker): one byte of endianness (`v` little, `V` big), one byte of marker space
//! (`P` pixels, `N` normalised), eight f32 intrinsics (f, cx, cy, k1, k2, k3, p1, p2 — OpenCV's
//! tangential convention), then counted lists of cameras (i32 image, column-major f32 rotation,
//! f32 translation, `x_cam = R X + t`), points (i32 track, f32 position) and markers (i32 image,
//! i32 track, f32 x, y).

use std::path::Path;

use crate::IoError;

/// A camera of a libmv problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LibmvCamera {
    /// Image number (may have gaps).
    pub image: usize,
    /// Rotation, row-major here (the file stores it column-major).
    pub rotation: [[f64; 3]; 3],
    /// Translation.
    pub translation: [f64; 3],
}

/// A reconstructed point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LibmvPoint {
    /// Track number (may have gaps).
    pub track: usize,
    /// Position.
    pub position: [f64; 3],
}

/// A 2-D observation of a track in an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LibmvMarker {
    /// Image number.
    pub image: usize,
    /// Track number.
    pub track: usize,
    /// Position (pixels from the top-left corner, or normalised coordinates).
    pub xy: [f64; 2],
}

/// A libmv problem as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct LibmvProblem {
    /// Markers in pixels (`P`) rather than normalised coordinates (`N`).
    pub pixel_space: bool,
    /// f, cx, cy, k1, k2, k3, p1, p2.
    pub intrinsics: [f64; 8],
    /// Cameras.
    pub cameras: Vec<LibmvCamera>,
    /// Points.
    pub points: Vec<LibmvPoint>,
    /// Markers.
    pub markers: Vec<LibmvMarker>,
}

struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
    big_endian: bool,
}

impl Reader<'_> {
    fn word(&mut self, what: &str) -> Result<[u8; 4], IoError> {
        let b = self.bytes.get(self.at..self.at + 4).ok_or_else(|| {
            IoError::invalid(
                self.path,
                format!("file ends at byte {} before {what}", self.at),
            )
        })?;
        self.at += 4;
        let mut w = [b[0], b[1], b[2], b[3]];
        if self.big_endian {
            w.reverse();
        }
        Ok(w)
    }

    fn real(&mut self, what: &str) -> Result<f64, IoError> {
        let at = self.at;
        let v = f32::from_le_bytes(self.word(what)?) as f64;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(IoError::invalid(
                self.path,
                format!("{what} at byte {at} is not finite"),
            ))
        }
    }

    fn index(&mut self, what: &str) -> Result<usize, IoError> {
        let at = self.at;
        let v = i32::from_le_bytes(self.word(what)?);
        usize::try_from(v).map_err(|_| {
            IoError::invalid(self.path, format!("{what} at byte {at} is negative ({v})"))
        })
    }

    /// A count, checked against the bytes left (each item takes at least `item_bytes`).
    fn count(&mut self, what: &str, item_bytes: usize) -> Result<usize, IoError> {
        let at = self.at;
        let n = self.index(what)?;
        let left = self.bytes.len().saturating_sub(self.at);
        if n.saturating_mul(item_bytes) > left {
            return Err(IoError::invalid(
                self.path,
                format!("{what} at byte {at} is {n}, but only {left} bytes follow"),
            ));
        }
        Ok(n)
    }
}

/// Reads a libmv problem file.
pub fn read_libmv(path: &Path) -> Result<LibmvProblem, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    let big_endian = match bytes.first() {
        Some(b'v') => false,
        Some(b'V') => true,
        other => {
            return Err(IoError::invalid(
                path,
                format!(
                    "byte 0 is {other:?}; 'v' (little-endian) or 'V' (big-endian) was expected"
                ),
            ));
        }
    };
    let pixel_space = match bytes.get(1) {
        Some(b'P') => true,
        Some(b'N') => false,
        other => {
            return Err(IoError::invalid(
                path,
                format!("byte 1 is {other:?}; 'P' (pixels) or 'N' (normalised) was expected"),
            ));
        }
    };
    let mut r = Reader {
        path,
        bytes: &bytes,
        at: 2,
        big_endian,
    };
    let mut intrinsics = [0.0; 8];
    for v in &mut intrinsics {
        *v = r.real("an intrinsic")?;
    }
    let n = r.count("the camera count", 52)?;
    let mut cameras = Vec::with_capacity(n);
    for _ in 0..n {
        let image = r.index("a camera's image number")?;
        let mut rotation = [[0.0; 3]; 3];
        for k in 0..9 {
            rotation[k % 3][k / 3] = r.real("a rotation entry")?;
        }
        let mut translation = [0.0; 3];
        for v in &mut translation {
            *v = r.real("a translation entry")?;
        }
        cameras.push(LibmvCamera {
            image,
            rotation,
            translation,
        });
    }
    let n = r.count("the point count", 16)?;
    let mut points = Vec::with_capacity(n);
    for _ in 0..n {
        let track = r.index("a point's track number")?;
        let mut position = [0.0; 3];
        for v in &mut position {
            *v = r.real("a point coordinate")?;
        }
        points.push(LibmvPoint { track, position });
    }
    let n = r.count("the marker count", 16)?;
    let mut markers = Vec::with_capacity(n);
    for _ in 0..n {
        let image = r.index("a marker's image number")?;
        let track = r.index("a marker's track number")?;
        let xy = [
            r.real("a marker coordinate")?,
            r.real("a marker coordinate")?,
        ];
        markers.push(LibmvMarker { image, track, xy });
    }
    if r.at != bytes.len() {
        return Err(IoError::invalid(
            path,
            format!("{} bytes after the last marker", bytes.len() - r.at),
        ));
    }
    Ok(LibmvProblem {
        pixel_space,
        intrinsics,
        cameras,
        points,
        markers,
    })
}
