//! Bundle-adjustment problems in the BAL text format (Agarwal et al. 2010), as used by Ceres's
//! `bundle_adjuster`: a header `C P N`, `N` observations `camera point x y`, `C` cameras of nine
//! numbers (angle-axis, translation, f, k1, k2), `P` points of three. Whitespace-separated tokens;
//! line breaks carry no meaning.

use std::path::Path;

use crate::{IoError, fsutil};

/// One BAL observation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BalObservation {
    /// Camera index.
    pub camera: usize,
    /// Point index.
    pub point: usize,
    /// Position relative to the principal point, y up, pixels.
    pub xy: [f64; 2],
}

/// A BAL problem as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct BalProblem {
    /// Per camera: angle-axis (3), translation (3), f, k1, k2 — BAL's own frame (looking down −z).
    pub cameras: Vec<[f64; 9]>,
    /// Point positions.
    pub points: Vec<[f64; 3]>,
    /// Observations.
    pub observations: Vec<BalObservation>,
}

/// Reads a BAL text file.
pub fn read_bal(path: &Path) -> Result<BalProblem, IoError> {
    let text = fsutil::read_text(path)?;
    let mut tokens = text.split_ascii_whitespace().enumerate();
    let mut next = |what: &str| -> Result<&str, IoError> {
        tokens
            .next()
            .map(|(_, t)| t)
            .ok_or_else(|| IoError::invalid(path, format!("file ends before {what}")))
    };
    let int = |t: &str, what: &str| -> Result<usize, IoError> {
        t.parse().map_err(|_| {
            IoError::invalid(path, format!("{what}: expected an integer, found \"{t}\""))
        })
    };
    let real = |t: &str, what: &str| -> Result<f64, IoError> {
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                IoError::invalid(path, format!("{what}: expected a number, found \"{t}\""))
            })
    };
    let n_cameras = int(next("the camera count")?, "camera count")?;
    let n_points = int(next("the point count")?, "point count")?;
    let n_obs = int(next("the observation count")?, "observation count")?;
    // Counts come from the file: cap the preallocation by what the text can hold.
    let max_tokens = text.len() / 2 + 1;
    let mut observations = Vec::with_capacity(n_obs.min(max_tokens / 4));
    for k in 0..n_obs {
        let camera = int(next("an observation")?, "observation camera")?;
        let point = int(next("an observation")?, "observation point")?;
        let x = real(next("an observation")?, "observation x")?;
        let y = real(next("an observation")?, "observation y")?;
        if camera >= n_cameras || point >= n_points {
            return Err(IoError::invalid(
                path,
                format!("observation {k} refers to camera {camera} / point {point} out of range"),
            ));
        }
        observations.push(BalObservation {
            camera,
            point,
            xy: [x, y],
        });
    }
    let mut cameras = Vec::with_capacity(n_cameras.min(max_tokens / 9));
    for _ in 0..n_cameras {
        let mut c = [0.0; 9];
        for v in c.iter_mut() {
            *v = real(next("a camera")?, "camera parameter")?;
        }
        cameras.push(c);
    }
    let mut points = Vec::with_capacity(n_points.min(max_tokens / 3));
    for _ in 0..n_points {
        let mut p = [0.0; 3];
        for v in p.iter_mut() {
            *v = real(next("a point")?, "point coordinate")?;
        }
        points.push(p);
    }
    Ok(BalProblem {
        cameras,
        points,
        observations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_small_problem_and_rejects_truncation() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.txt");
        std::fs::write(
            &p,
            "1 2 2\n0 0 1.5 -2\n0 1 3 4\n0.1 0.2 0.3 1 2 3 500 -0.1 0.01\n1 2 3\n4 5 6\n",
        )
        .unwrap();
        let b = read_bal(&p).unwrap();
        assert_eq!(b.observations[1].xy, [3.0, 4.0]);
        assert_eq!(b.cameras[0][6], 500.0);
        assert_eq!(b.points[1], [4.0, 5.0, 6.0]);
        std::fs::write(&p, "1 2 2\n0 0 1.5 -2\n0 1 3 4\n0.1 0.2\n").unwrap();
        assert!(
            read_bal(&p)
                .unwrap_err()
                .to_string()
                .contains("ends before a camera")
        );
        std::fs::write(&p, "1 1 1\n3 0 1 1\n").unwrap();
        assert!(
            read_bal(&p)
                .unwrap_err()
                .to_string()
                .contains("out of range")
        );
    }
}
