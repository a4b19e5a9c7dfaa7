//! Tie-point clouds as binary little-endian PLY: per vertex the position (f64, so projected
//! coordinates keep their millimetres), the number of observations, and a bit mask of the epochs
//! that observe it (bit e for epoch e; the header names the epochs in order). The mask is one
//! `uint` property per 32 epochs: `epochs` (epochs 0–31, all a project of up to 32 epochs
//! writes, so viewers show it as one scalar field), then `epochs_32`, `epochs_64`, … for larger
//! projects, up to [`EpochSet::CAPACITY`] epochs.

use std::io::{BufRead, Read, Write};
use std::path::Path;

use nalgebra::Vector3;

use crate::{IoError, fsutil};

/// The epochs that observe a tie point, by index: a fixed-size bit set, so that a tie point
/// stays `Copy` and a million of them allocate nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct EpochSet([u64; 4]);

impl EpochSet {
    /// The most epochs a set holds (and so a project can have).
    pub const CAPACITY: usize = 256;

    /// The set of `epoch` alone. Panics beyond [`EpochSet::CAPACITY`], which projects are
    /// checked against when loaded.
    pub fn only(epoch: usize) -> EpochSet {
        let mut set = EpochSet::default();
        set.insert(epoch);
        set
    }

    /// Adds `epoch` (panics beyond [`EpochSet::CAPACITY`]).
    pub fn insert(&mut self, epoch: usize) {
        assert!(epoch < Self::CAPACITY, "epoch {epoch} beyond the epoch set");
        self.0[epoch / 64] |= 1 << (epoch % 64);
    }

    /// Whether `epoch` is in the set.
    pub fn contains(&self, epoch: usize) -> bool {
        epoch < Self::CAPACITY && self.0[epoch / 64] & (1 << (epoch % 64)) != 0
    }

    /// Epochs in the set.
    pub fn len(&self) -> usize {
        self.0.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Whether no epoch is in the set.
    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|w| *w == 0)
    }

    /// Whether every epoch of `other` is in the set.
    pub fn contains_all(&self, other: &EpochSet) -> bool {
        self.0.iter().zip(&other.0).all(|(a, b)| a & b == *b)
    }

    /// Whether an epoch other than `epoch` is in the set.
    pub fn has_other_than(&self, epoch: usize) -> bool {
        let mut rest = *self;
        if epoch < Self::CAPACITY {
            rest.0[epoch / 64] &= !(1 << (epoch % 64));
        }
        rest.0.iter().any(|w| *w != 0)
    }

    /// Epochs 32·k to 32·k + 31 as the bits of a `u32` (the PLY's k-th mask property).
    fn word32(&self, k: usize) -> u32 {
        (self.0[k / 2] >> (32 * (k % 2))) as u32
    }

    /// Sets epochs 32·k to 32·k + 31 from the bits of `bits`.
    fn set_word32(&mut self, k: usize, bits: u32) {
        self.0[k / 2] |= u64::from(bits) << (32 * (k % 2));
    }
}

impl FromIterator<usize> for EpochSet {
    fn from_iter<I: IntoIterator<Item = usize>>(epochs: I) -> EpochSet {
        let mut set = EpochSet::default();
        for e in epochs {
            set.insert(e);
        }
        set
    }
}

/// One tie point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiePoint {
    /// World position.
    pub position: Vector3<f64>,
    /// Number of image observations.
    pub observations: u16,
    /// The epochs that observe it.
    pub epochs: EpochSet,
}

/// The name of the k-th mask property: `epochs`, then `epochs_32`, `epochs_64`, ….
fn mask_property(k: usize) -> String {
    if k == 0 {
        "epochs".to_string()
    } else {
        format!("epochs_{}", 32 * k)
    }
}

/// Writes tie points; `epochs` are the names behind the mask bits (at most
/// [`EpochSet::CAPACITY`]).
pub fn write_tiepoints(path: &Path, epochs: &[String], points: &[TiePoint]) -> Result<(), IoError> {
    if epochs.len() > EpochSet::CAPACITY {
        return Err(IoError::invalid(
            path,
            format!(
                "{} epochs: a tie-point file holds at most {}",
                epochs.len(),
                EpochSet::CAPACITY
            ),
        ));
    }
    let words = epochs.len().div_ceil(32).max(1);
    fsutil::write_atomically(path, |w| {
        let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
        header.push_str("comment timesift tie points; epochs bit mask: ");
        header.push_str(&epochs.join(" "));
        header.push('\n');
        header.push_str(&format!(
            "element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             property ushort observations\n",
            points.len()
        ));
        for k in 0..words {
            header.push_str(&format!("property uint {}\n", mask_property(k)));
        }
        header.push_str("end_header\n");
        let mut body = Vec::with_capacity(header.len() + points.len() * (26 + 4 * words));
        body.extend_from_slice(header.as_bytes());
        for p in points {
            for v in p.position.iter() {
                body.extend_from_slice(&v.to_le_bytes());
            }
            body.extend_from_slice(&p.observations.to_le_bytes());
            for k in 0..words {
                body.extend_from_slice(&p.epochs.word32(k).to_le_bytes());
            }
        }
        w.write_all(&body).map_err(|e| IoError::io(path, e))
    })
}

/// Reads a file written by [`write_tiepoints`]: the epoch names and the points.
pub fn read_tiepoints(path: &Path) -> Result<(Vec<String>, Vec<TiePoint>), IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let file_len = file.metadata().map_err(|e| IoError::io(path, e))?.len();
    let mut reader = std::io::BufReader::new(file);
    let mut header_len = 0u64;
    let mut epochs = Vec::new();
    let mut count = None;
    let mut properties: Vec<String> = Vec::new();
    let mut line = String::new();
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .map_err(|e| IoError::io(path, e))?;
        if n == 0 {
            return Err(IoError::invalid(path, "PLY header has no end_header"));
        }
        header_len += n as u64;
        let l = line.trim_end();
        if let Some(names) = l.strip_prefix("comment timesift tie points; epochs bit mask:") {
            epochs = names.split_whitespace().map(str::to_string).collect();
        } else if let Some(n) = l.strip_prefix("element vertex ") {
            count = Some(n.trim().parse::<usize>().map_err(|_| {
                IoError::invalid(path, format!("bad vertex count \"{}\"", n.trim()))
            })?);
        } else if let Some(p) = l.strip_prefix("property ") {
            properties.push(p.to_string());
        } else if l == "end_header" {
            break;
        }
    }
    let count = count.ok_or_else(|| IoError::invalid(path, "PLY header has no vertex element"))?;
    if epochs.len() > EpochSet::CAPACITY {
        return Err(IoError::invalid(
            path,
            format!(
                "the header names {} epochs; a tie-point file holds at most {}",
                epochs.len(),
                EpochSet::CAPACITY
            ),
        ));
    }
    let words = properties.len().saturating_sub(4);
    let expected: Vec<String> = ["double x", "double y", "double z", "ushort observations"]
        .into_iter()
        .map(str::to_string)
        .chain((0..words).map(|k| format!("uint {}", mask_property(k))))
        .collect();
    if words != epochs.len().div_ceil(32).max(1) || properties != expected {
        return Err(IoError::invalid(
            path,
            format!(
                "vertex properties {:?} for {} epochs: expected x, y, z (double), observations \
                 (ushort), then epochs, epochs_32, … (uint, one per 32 epochs)",
                properties,
                epochs.len()
            ),
        ));
    }
    let record_len = 26 + 4 * words;
    // The count is the header's claim: the vertices must be in the file before they are
    // allocated.
    let body = file_len.saturating_sub(header_len);
    if (count as u64).saturating_mul(record_len as u64) > body {
        return Err(IoError::invalid(
            path,
            format!(
                "the header counts {count} vertices of {record_len} bytes; {body} bytes follow it"
            ),
        ));
    }
    let mut points = Vec::with_capacity(count);
    let mut record = vec![0u8; record_len];
    for k in 0..count {
        reader
            .read_exact(&mut record)
            .map_err(|_| IoError::invalid(path, format!("file ends at vertex {k} of {count}")))?;
        let f = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&record[i * 8..i * 8 + 8]);
            f64::from_le_bytes(b)
        };
        let mut set = EpochSet::default();
        for k in 0..words {
            let b = &record[26 + 4 * k..30 + 4 * k];
            set.set_word32(k, u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        }
        if (epochs.len()..32 * words).any(|e| set.contains(e)) {
            return Err(IoError::invalid(
                path,
                format!(
                    "vertex {k} is seen in an epoch beyond the {} named",
                    epochs.len()
                ),
            ));
        }
        points.push(TiePoint {
            position: Vector3::new(f(0), f(1), f(2)),
            observations: u16::from_le_bytes([record[24], record[25]]),
            epochs: set,
        });
    }
    Ok((epochs, points))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiepoints_round_trip_and_truncation_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.ply");
        let points = vec![
            TiePoint {
                position: Vector3::new(512_345.123_4, 6_123_456.789_1, 12.5),
                observations: 3,
                epochs: [0, 2].into_iter().collect(),
            },
            TiePoint {
                position: Vector3::new(-1.0, 2.0, -3.0),
                observations: 2,
                epochs: EpochSet::only(1),
            },
        ];
        let epochs = vec!["2018".to_string(), "2019".into(), "2020".into()];
        write_tiepoints(&path, &epochs, &points).unwrap();
        let (e, p) = read_tiepoints(&path).unwrap();
        assert_eq!(e, epochs);
        assert_eq!(p, points);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        let err = read_tiepoints(&path).unwrap_err().to_string();
        // Caught from the header's count and the file's length, before a vertex is read.
        assert!(
            err.contains("t.ply") && err.contains("counts 2 vertices"),
            "{err}"
        );
    }

    #[test]
    fn more_than_32_epochs_take_more_mask_properties() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.ply");
        let epochs: Vec<String> = (0..70).map(|e| format!("e{e}")).collect();
        let points: Vec<TiePoint> = [vec![0, 31], vec![32, 69], vec![5, 33, 64]]
            .into_iter()
            .map(|set| TiePoint {
                position: Vector3::new(1.0, 2.0, 3.0),
                observations: set.len() as u16,
                epochs: set.into_iter().collect(),
            })
            .collect();
        write_tiepoints(&path, &epochs, &points).unwrap();
        let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()).to_string();
        assert!(text.contains(
            "property uint epochs\nproperty uint epochs_32\nproperty uint epochs_64\nend_header"
        ));
        let (e, p) = read_tiepoints(&path).unwrap();
        assert_eq!(e, epochs);
        assert_eq!(p, points);
        assert!(p[1].epochs.contains(69) && !p[1].epochs.contains(37));
        assert_eq!(p[2].epochs.len(), 3);
        assert!(EpochSet::default().is_empty() && !p[0].epochs.is_empty());
        assert!(p[2].epochs.has_other_than(33) && !EpochSet::only(33).has_other_than(33));
        assert!(p[2].epochs.contains_all(&[5, 64].into_iter().collect()));
        // Beyond the capacity: a clear error, no file.
        let many: Vec<String> = (0..=EpochSet::CAPACITY).map(|e| format!("e{e}")).collect();
        let err = write_tiepoints(&dir.path().join("u.ply"), &many, &[]).unwrap_err();
        assert!(err.to_string().contains("at most 256"), "{err}");
        assert!(!dir.path().join("u.ply").exists());
        // A point seen in an epoch the header does not name is refused.
        let stray = dir.path().join("s.ply");
        let three = vec!["a".to_string(), "b".into(), "c".into()];
        let odd = TiePoint {
            epochs: EpochSet::only(5),
            ..points[0]
        };
        write_tiepoints(&stray, &three, &[odd]).unwrap();
        let err = read_tiepoints(&stray).unwrap_err().to_string();
        assert!(
            err.contains("vertex 0") && err.contains("beyond the 3 named"),
            "{err}"
        );
        // A mask property missing or misnamed is refused.
        let bytes = std::fs::read(&path).unwrap();
        let broken = String::from_utf8_lossy(&bytes).replacen("epochs_32", "epochs_33", 1);
        std::fs::write(&path, broken.as_bytes()).unwrap();
        let err = read_tiepoints(&path).unwrap_err().to_string();
        assert!(err.contains("expected x, y, z"), "{err}");
    }
}
