//! The truth a synthetic project carries beside its inputs, as `timesift-synth` writes it
//! (`truth/`, docs/design.md's synthetic scenes): `points.csv` (every GCP, check point and
//! scale-bar target exactly) and `gnss_bias.csv` (each epoch's true GNSS bias). Read by the
//! evaluation of tests and benchmarks; the same CSV rules as the project's inputs.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;

use crate::IoError;
use crate::csv_inputs::{non_empty, number, read_rows};

/// One row of `truth/points.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct TruePoint {
    /// Point name.
    pub name: String,
    /// What it is (`gcp`, `check`, `target`, …).
    pub kind: String,
    /// Exact world position.
    pub position: Vector3<f64>,
}

/// Reads `truth/points.csv` (`name,kind,x,y,z`).
pub fn read_true_points(path: &Path) -> Result<Vec<TruePoint>, IoError> {
    let rows = read_rows(
        path,
        &[&["name", "kind", "x", "y", "z"]],
        &[5],
        "name,kind,x,y,z",
    )?;
    rows.iter()
        .map(|row| {
            Ok(TruePoint {
                name: non_empty(path, row, 0, "name")?,
                kind: non_empty(path, row, 1, "kind")?,
                position: Vector3::new(
                    number(path, row, 2, "x")?,
                    number(path, row, 3, "y")?,
                    number(path, row, 4, "z")?,
                ),
            })
        })
        .collect()
}

/// Reads `truth/gnss_bias.csv` (`epoch,east,north,up`): each epoch's true GNSS bias, metres.
/// An epoch named twice is an error.
pub fn read_gnss_bias(path: &Path) -> Result<BTreeMap<String, [f64; 3]>, IoError> {
    let rows = read_rows(
        path,
        &[&["epoch", "east", "north", "up"]],
        &[4],
        "epoch,east,north,up",
    )?;
    let mut biases = BTreeMap::new();
    for row in &rows {
        let epoch = non_empty(path, row, 0, "epoch")?;
        let bias = [
            number(path, row, 1, "east")?,
            number(path, row, 2, "north")?,
            number(path, row, 3, "up")?,
        ];
        if biases.insert(epoch.clone(), bias).is_some() {
            return Err(IoError::line(
                path,
                row.line,
                format!("epoch `{epoch}` listed twice"),
            ));
        }
    }
    Ok(biases)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("truth.csv");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn true_points_and_biases_are_read_with_their_header() {
        let (_d, path) = file("name,kind,x,y,z\nGCP1,gcp,1.5,2,3\nT7,target,-4,5.25,6\n");
        let points = read_true_points(&path).unwrap();
        assert_eq!(points.len(), 2);
        assert_eq!(points[1].name, "T7");
        assert_eq!(points[1].kind, "target");
        assert_eq!(points[1].position, Vector3::new(-4.0, 5.25, 6.0));
        let (_d, path) = file("epoch,east,north,up\n2023-06-15,0.1,-0.2,0.3\n");
        let biases = read_gnss_bias(&path).unwrap();
        assert_eq!(biases["2023-06-15"], [0.1, -0.2, 0.3]);
    }

    #[test]
    fn bad_rows_name_their_line() {
        let (_d, path) = file("epoch,east,north,up\ne1,0.1,x,0.3\n");
        let message = read_gnss_bias(&path).unwrap_err().to_string();
        assert!(
            message.contains("line 2") && message.contains("north"),
            "{message}"
        );
        let (_d, path) = file("epoch,east,north,up\ne1,0,0,0\ne1,1,1,1\n");
        let message = read_gnss_bias(&path).unwrap_err().to_string();
        assert!(
            message.contains("line 3") && message.contains("twice"),
            "{message}"
        );
        let (_d, path) = file("name,kind,x,y,z\nA,gcp,1,2\n");
        let message = read_true_points(&path).unwrap_err().to_string();
        assert!(
            message.contains("line 2") && message.contains("name,kind,x,y,z"),
            "{message}"
        );
    }
}
