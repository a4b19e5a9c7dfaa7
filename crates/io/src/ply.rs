//! Tie-point clouds as binary little-endian PLY: per vertex the position (f64, so projected
//! coordinates keep their millimetres), the number of observations, and a bit mask of the epochs
//! that observe it (bit e for epoch e; the header names the epochs in order).

use std::io::{BufRead, Read, Write};
use std::path::Path;

use nalgebra::Vector3;

use crate::{IoError, fsutil};

/// One tie point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiePoint {
    /// World position.
    pub position: Vector3<f64>,
    /// Number of image observations.
    pub observations: u16,
    /// Bit e set when epoch e observes the point.
    pub epochs: u32,
}

/// Writes tie points; `epochs` are the names behind the mask bits (at most 32).
pub fn write_tiepoints(path: &Path, epochs: &[String], points: &[TiePoint]) -> Result<(), IoError> {
    if epochs.len() > 32 {
        return Err(IoError::invalid(
            path,
            format!("{} epochs do not fit the 32-bit epoch mask", epochs.len()),
        ));
    }
    fsutil::write_atomically(path, |w| {
        let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
        header.push_str("comment timesift tie points; epochs bit mask: ");
        header.push_str(&epochs.join(" "));
        header.push('\n');
        header.push_str(&format!(
            "element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             property ushort observations\nproperty uint epochs\nend_header\n",
            points.len()
        ));
        let mut body = Vec::with_capacity(header.len() + points.len() * 30);
        body.extend_from_slice(header.as_bytes());
        for p in points {
            for v in p.position.iter() {
                body.extend_from_slice(&v.to_le_bytes());
            }
            body.extend_from_slice(&p.observations.to_le_bytes());
            body.extend_from_slice(&p.epochs.to_le_bytes());
        }
        w.write_all(&body).map_err(|e| IoError::io(path, e))
    })
}

/// Reads a file written by [`write_tiepoints`]: the epoch names and the points.
pub fn read_tiepoints(path: &Path) -> Result<(Vec<String>, Vec<TiePoint>), IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let mut epochs = Vec::new();
    let mut count = None;
    let mut line = String::new();
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .map_err(|e| IoError::io(path, e))?;
        if n == 0 {
            return Err(IoError::invalid(path, "PLY header has no end_header"));
        }
        let l = line.trim_end();
        if let Some(names) = l.strip_prefix("comment timesift tie points; epochs bit mask:") {
            epochs = names.split_whitespace().map(str::to_string).collect();
        } else if let Some(n) = l.strip_prefix("element vertex ") {
            count = Some(n.trim().parse::<usize>().map_err(|_| {
                IoError::invalid(path, format!("bad vertex count \"{}\"", n.trim()))
            })?);
        } else if l == "end_header" {
            break;
        }
    }
    let count = count.ok_or_else(|| IoError::invalid(path, "PLY header has no vertex element"))?;
    let mut points = Vec::with_capacity(count);
    let mut record = [0u8; 30];
    for k in 0..count {
        reader
            .read_exact(&mut record)
            .map_err(|_| IoError::invalid(path, format!("file ends at vertex {k} of {count}")))?;
        let f = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&record[i * 8..i * 8 + 8]);
            f64::from_le_bytes(b)
        };
        points.push(TiePoint {
            position: Vector3::new(f(0), f(1), f(2)),
            observations: u16::from_le_bytes([record[24], record[25]]),
            epochs: u32::from_le_bytes([record[26], record[27], record[28], record[29]]),
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
                epochs: 0b101,
            },
            TiePoint {
                position: Vector3::new(-1.0, 2.0, -3.0),
                observations: 2,
                epochs: 0b10,
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
        assert!(
            err.contains("t.ply") && err.contains("vertex 1 of 2"),
            "{err}"
        );
    }
}
