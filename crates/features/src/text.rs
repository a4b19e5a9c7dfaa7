//! The feature text format of docs/design.md, for inspecting and comparing features outside timesift:
//! a first line `N D` (count; descriptor length: values for float, bytes for binary), then one line
//! per keypoint, `x y scale orientation` followed by the D descriptor values (floats, or bytes
//! 0–255). Pixel convention of docs/design.md; scale is σ in pixels, orientation in radians.
//!
//! The format does not say whether descriptors are binary, so the reader is told what to expect.
//! Keypoint response and octave are not stored: they read back as 0.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use timesift_core::{Descriptors, Keypoint};

use crate::{FeatureError, Features};

/// Writes `features` to `path` atomically (`timesift_io::fsutil::write_atomically`).
pub fn write(path: &Path, features: &Features) -> Result<(), FeatureError> {
    let n = features.keypoints.len();
    if features.descriptors.len() != n {
        return Err(FeatureError::Format {
            path: path.to_path_buf(),
            line: 0,
            message: format!(
                "{} keypoints but {} descriptors",
                n,
                features.descriptors.len()
            ),
        });
    }
    let d = features.descriptors.width();
    let mut text = String::with_capacity(n * (40 + 4 * d));
    let _ = writeln!(text, "{n} {d}");
    for (i, k) in features.keypoints.iter().enumerate() {
        let _ = write!(text, "{} {} {} {}", k.x, k.y, k.scale, k.orientation);
        match &features.descriptors {
            Descriptors::Float { dim, data } => {
                for v in &data[i * dim..(i + 1) * dim] {
                    let _ = write!(text, " {v}");
                }
            }
            Descriptors::Binary { bytes, data } => {
                for v in &data[i * bytes..(i + 1) * bytes] {
                    let _ = write!(text, " {v}");
                }
            }
        }
        text.push('\n');
    }
    timesift_io::fsutil::write_atomically(path, |w| {
        w.write_all(text.as_bytes())
            .map_err(|e| timesift_io::IoError::io(path, e))
    })?;
    Ok(())
}

/// What kind of descriptor a feature file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DescriptorKind {
    /// Real-valued descriptors (SIFT, RootSIFT).
    Float,
    /// Bytes compared by Hamming distance (LDB).
    Binary,
}

/// Reads a feature text file; errors name the file and line.
pub fn read(path: &Path, kind: DescriptorKind) -> Result<Features, FeatureError> {
    let text = std::fs::read_to_string(path).map_err(|source| FeatureError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let error = |line: usize, message: String| FeatureError::Format {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    let (_, header) = lines
        .next()
        .ok_or_else(|| error(1, "empty file, expected the header `N D`".into()))?;
    let header = Header::parse(header, &error)?;
    let n = header.n;
    // Capacity from what the file can hold, not from what the header claims.
    let mut values = Values {
        keypoints: Vec::with_capacity(n.min(text.len() / 8 + 1)),
        floats: Vec::new(),
        bytes: Vec::new(),
    };
    for (number, line) in lines.by_ref().take(n) {
        values.push_line(number, line, &header, kind, &error)?;
    }
    if values.keypoints.len() != n {
        return Err(error(
            values.keypoints.len() + 2,
            format!(
                "file ends after {} keypoints, header announced {n}",
                values.keypoints.len()
            ),
        ));
    }
    if let Some((number, line)) = lines.find(|(_, l)| !l.trim().is_empty()) {
        return Err(error(
            number,
            format!(
                "unexpected content after {n} keypoints: `{}`",
                line.chars().take(40).collect::<String>()
            ),
        ));
    }
    Ok(values.into_features(header.d, kind))
}

/// An error at a line of the file being read, with its message.
type LineError<'a> = dyn Fn(usize, String) -> FeatureError + 'a;

/// The header line `N D` of a feature file.
struct Header {
    /// Keypoints.
    n: usize,
    /// Descriptor length.
    d: usize,
    /// Values on a keypoint line: geometry and descriptor.
    values_per_line: usize,
}

impl Header {
    /// The header in `line` (line 1), or the error that says what is wrong with it.
    fn parse(line: &str, error: &LineError) -> Result<Header, FeatureError> {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let parse_count = |s: &str| s.parse::<usize>().ok();
        let (n, d) = match fields.as_slice() {
            [n, d] => match (parse_count(n), parse_count(d)) {
                (Some(n), Some(d)) => (n, d),
                _ => {
                    return Err(error(1, format!("header `{line}` is not two counts `N D`")));
                }
            },
            _ => {
                return Err(error(1, format!("header `{line}` is not two counts `N D`")));
            }
        };
        if d == 0 {
            return Err(error(
                1,
                "descriptor length D is 0; expected at least 1".into(),
            ));
        }
        let Some(values_per_line) = d.checked_add(4) else {
            return Err(error(1, format!("descriptor length {d} is not plausible")));
        };
        Ok(Header {
            n,
            d,
            values_per_line,
        })
    }
}

/// The keypoints and descriptor values read so far (floats or bytes, as the reader expects).
struct Values {
    keypoints: Vec<Keypoint>,
    floats: Vec<f32>,
    bytes: Vec<u8>,
}

impl Values {
    /// Reads keypoint line `number`: its geometry and its descriptor values of `kind`.
    fn push_line(
        &mut self,
        number: usize,
        line: &str,
        header: &Header,
        kind: DescriptorKind,
        error: &LineError,
    ) -> Result<(), FeatureError> {
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() != header.values_per_line {
            return Err(error(
                number,
                format!(
                    "expected {} values (x y scale orientation + {}), found {}",
                    header.values_per_line,
                    header.d,
                    fields.len()
                ),
            ));
        }
        let mut geometry = [0.0f64; 4];
        for (g, f) in geometry.iter_mut().zip(&fields[..4]) {
            *g = f
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| error(number, format!("`{f}` is not a finite number")))?;
        }
        self.keypoints.push(Keypoint {
            x: geometry[0],
            y: geometry[1],
            scale: geometry[2],
            orientation: geometry[3],
            response: 0.0,
            octave: 0,
        });
        for f in &fields[4..] {
            match kind {
                DescriptorKind::Float => {
                    self.floats
                        .push(
                            f.parse::<f32>()
                                .ok()
                                .filter(|v| v.is_finite())
                                .ok_or_else(|| {
                                    error(
                                        number,
                                        format!("descriptor value `{f}` is not a finite number"),
                                    )
                                })?,
                        )
                }
                DescriptorKind::Binary => self.bytes.push(f.parse::<u8>().map_err(|_| {
                    error(number, format!("descriptor byte `{f}` is not in 0–255"))
                })?),
            }
        }
        Ok(())
    }

    /// The features read, with descriptors of length `d` and `kind`.
    fn into_features(self, d: usize, kind: DescriptorKind) -> Features {
        let descriptors = match kind {
            DescriptorKind::Float => Descriptors::Float {
                dim: d,
                data: self.floats,
            },
            DescriptorKind::Binary => Descriptors::Binary {
                bytes: d,
                data: self.bytes,
            },
        };
        Features {
            keypoints: self.keypoints,
            descriptors,
        }
    }
}
