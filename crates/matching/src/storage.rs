//! Versioned binary files for the features of one image and the matches of one pair, under the
//! project's work folder: runs resume from them and memory stays bounded (one image's features
//! in memory at a time). Little-endian, fixed-size records, an FNV-1a checksum at the end, so a
//! truncated or damaged file is an error that names it, never garbage.

use std::path::Path;

use timesift_core::{Descriptors, Keypoint};

use crate::{Match, MatchingError};

const FEATURE_MAGIC: &[u8; 8] = b"TSFEAT\0\0";
const MATCH_MAGIC: &[u8; 8] = b"TSMATCH\0";
/// Version written and read by this build.
pub const VERSION: u32 = 1;
const KEYPOINT_BYTES: usize = 40;
const MATCH_BYTES: usize = 12;

fn fnv1a(data: &[u8]) -> u64 {
    timesift_io::fingerprint::Fnv1a::of(data)
}

fn write_atomic(path: &Path, mut bytes: Vec<u8>) -> Result<(), MatchingError> {
    let sum = fnv1a(&bytes);
    bytes.extend_from_slice(&sum.to_le_bytes());
    timesift_io::fsutil::write_atomically(path, |w| {
        use std::io::Write;
        w.write_all(&bytes)
            .map_err(|e| timesift_io::IoError::io(path, e))
    })?;
    Ok(())
}

/// Reads a whole file, checks magic, version and checksum; returns the payload after the header.
fn read_checked(path: &Path, magic: &[u8; 8], what: &str) -> Result<Vec<u8>, MatchingError> {
    let corrupt = |message: String| MatchingError::Corrupt {
        path: path.to_path_buf(),
        message,
    };
    let bytes = std::fs::read(path).map_err(|source| MatchingError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if bytes.len() < 20 {
        return Err(corrupt(format!(
            "{} bytes: too short for a {what} file (truncated?)",
            bytes.len()
        )));
    }
    if &bytes[..8] != magic {
        return Err(corrupt(format!(
            "not a timesift {what} file (wrong magic bytes)"
        )));
    }
    let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if version != VERSION {
        return Err(corrupt(format!(
            "{what} file version {version}; this build reads version {VERSION}"
        )));
    }
    let (body, sum) = bytes.split_at(bytes.len() - 8);
    let mut stored = [0u8; 8];
    stored.copy_from_slice(sum);
    if fnv1a(body) != u64::from_le_bytes(stored) {
        return Err(corrupt(
            "checksum mismatch: the file is truncated or damaged; delete it to recompute".into(),
        ));
    }
    Ok(body[12..].to_vec())
}

/// Little-endian reader over a payload whose size was checked.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        out.copy_from_slice(&self.bytes[self.at..self.at + N]);
        self.at += N;
        out
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
}

/// Writes the features of one image.
pub fn write_features(
    path: &Path,
    keypoints: &[Keypoint],
    descriptors: &Descriptors,
) -> Result<(), MatchingError> {
    if descriptors.len() != keypoints.len() {
        return Err(MatchingError::Corrupt {
            path: path.to_path_buf(),
            message: format!(
                "refusing to write {} keypoints with {} descriptors",
                keypoints.len(),
                descriptors.len()
            ),
        });
    }
    let (kind, width, values) = match descriptors {
        Descriptors::Float { dim, data } => (0u8, *dim, data.len() * 4),
        Descriptors::Binary { bytes, data } => (1u8, *bytes, data.len()),
    };
    let mut out = Vec::with_capacity(40 + keypoints.len() * KEYPOINT_BYTES + values);
    out.extend_from_slice(FEATURE_MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&[kind, 0, 0, 0]);
    out.extend_from_slice(&(keypoints.len() as u64).to_le_bytes());
    out.extend_from_slice(&(width as u64).to_le_bytes());
    for k in keypoints {
        for v in [k.x, k.y, k.scale, k.orientation] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&k.response.to_le_bytes());
        out.extend_from_slice(&k.octave.to_le_bytes());
        out.extend_from_slice(&[0, 0]);
    }
    match descriptors {
        Descriptors::Float { data, .. } => {
            for v in data {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        Descriptors::Binary { data, .. } => out.extend_from_slice(data),
    }
    write_atomic(path, out)
}

/// Reads the features of one image.
pub fn read_features(path: &Path) -> Result<(Vec<Keypoint>, Descriptors), MatchingError> {
    let body = read_checked(path, FEATURE_MAGIC, "feature")?;
    let corrupt = |message: String| MatchingError::Corrupt {
        path: path.to_path_buf(),
        message,
    };
    if body.len() < 20 {
        return Err(corrupt("header is incomplete".into()));
    }
    let kind = body[0];
    let mut c = Cursor {
        bytes: &body,
        at: 4,
    };
    let (count, width) = (c.u64() as usize, c.u64() as usize);
    let value_size = match kind {
        0 => 4,
        1 => 1,
        other => return Err(corrupt(format!("unknown descriptor kind {other}"))),
    };
    // Every product checked: the counts are the file's claims.
    let expected = width
        .checked_mul(value_size)
        .and_then(|d| d.checked_add(KEYPOINT_BYTES))
        .and_then(|record| count.checked_mul(record))
        .and_then(|n| n.checked_add(20));
    if expected != Some(body.len()) {
        return Err(corrupt(format!(
            "header announces {count} keypoints with {width}-value descriptors, which does not \
             match the file's {} bytes",
            body.len() + 20
        )));
    }
    let mut keypoints = Vec::with_capacity(count);
    for _ in 0..count {
        let (x, y, scale, orientation) = (c.f64(), c.f64(), c.f64(), c.f64());
        let response = c.f32();
        let octave = i16::from_le_bytes(c.take());
        let _pad: [u8; 2] = c.take();
        keypoints.push(Keypoint {
            x,
            y,
            scale,
            orientation,
            response,
            octave,
        });
    }
    let descriptors = if kind == 0 {
        Descriptors::Float {
            dim: width,
            data: (0..count * width).map(|_| c.f32()).collect(),
        }
    } else {
        Descriptors::Binary {
            bytes: width,
            data: body[c.at..].to_vec(),
        }
    };
    Ok((keypoints, descriptors))
}

/// Writes the matches of one pair.
pub fn write_matches(path: &Path, matches: &[Match]) -> Result<(), MatchingError> {
    let mut out = Vec::with_capacity(28 + matches.len() * MATCH_BYTES);
    out.extend_from_slice(MATCH_MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(matches.len() as u64).to_le_bytes());
    for m in matches {
        out.extend_from_slice(&m.query.to_le_bytes());
        out.extend_from_slice(&m.train.to_le_bytes());
        out.extend_from_slice(&m.distance.to_le_bytes());
    }
    write_atomic(path, out)
}

/// Reads the matches of one pair.
pub fn read_matches(path: &Path) -> Result<Vec<Match>, MatchingError> {
    let body = read_checked(path, MATCH_MAGIC, "match")?;
    let mut c = Cursor {
        bytes: &body,
        at: 0,
    };
    if body.len() < 8 {
        return Err(MatchingError::Corrupt {
            path: path.to_path_buf(),
            message: "header is incomplete".into(),
        });
    }
    let count = c.u64() as usize;
    if count
        .checked_mul(MATCH_BYTES)
        .and_then(|n| n.checked_add(8))
        != Some(body.len())
    {
        return Err(MatchingError::Corrupt {
            path: path.to_path_buf(),
            message: format!(
                "header announces {count} matches, the file holds {} bytes",
                body.len() + 20
            ),
        });
    }
    Ok((0..count)
        .map(|_| Match {
            query: c.u32(),
            train: c.u32(),
            distance: c.f32(),
        })
        .collect())
}
