//! The CSV inputs of a project (docs/design.md): `gcps.csv`, `checkpoints.csv`, `markers.csv`,
//! `gnss.csv`, `stable.csv`, `stable_points.csv`, `fiducials.csv` and `scalebars.csv` (scale bars
//! between named targets, as close-range projects like `soil-pit` need).
//!
//! Rules common to all: comma-separated, `#` starts a comment line, blank lines are skipped, and an
//! optional first line naming the columns is recognised and skipped. Every record keeps its line
//! number so that later validation (unknown point, unknown image) can name it.

use std::path::Path;

use nalgebra::{Vector2, Vector3};

use crate::wkt::{Polygon, parse_polygons};
use crate::{IoError, fsutil};

/// A ground control point or check point with object coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlPoint {
    /// Point name, unique within its file.
    pub name: String,
    /// Object coordinates (E, N, H) in the project CRS, metres.
    pub position: Vector3<f64>,
    /// Standard deviations (horizontal, vertical) in metres, when given.
    pub sigma: Option<(f64, f64)>,
    /// Line in the file.
    pub line: usize,
}

/// A natural point on stable ground (`stable_points.csv`): no coordinates, only a name that
/// markers of several epochs measure, and optionally how far it may have moved.
#[derive(Debug, Clone, PartialEq)]
pub struct StablePointInput {
    /// Point name, unique within its file.
    pub name: String,
    /// Standard deviations (horizontal, vertical) of its stability in metres, when given.
    pub sigma: Option<(f64, f64)>,
    /// Line in the file.
    pub line: usize,
}

/// An image observation of a control or check point.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// Image path relative to the project directory.
    pub image: String,
    /// Point name (in gcps.csv or checkpoints.csv).
    pub name: String,
    /// Pixel position (docs/design.md convention).
    pub pixel: Vector2<f64>,
    /// Line in the file.
    pub line: usize,
}

/// A camera-centre prior from GNSS.
#[derive(Debug, Clone, PartialEq)]
pub struct GnssPrior {
    /// Image path relative to the project directory.
    pub image: String,
    /// Camera centre in the project CRS, metres.
    pub position: Vector3<f64>,
    /// Standard deviations (horizontal, vertical) in metres, when given.
    pub sigma: Option<(f64, f64)>,
    /// Line in the file.
    pub line: usize,
}

/// A stable area: one or more polygons.
#[derive(Debug, Clone, PartialEq)]
pub struct StableArea {
    /// Optional name given before the geometry.
    pub name: Option<String>,
    /// The polygons.
    pub polygons: Vec<Polygon>,
    /// Line in the file.
    pub line: usize,
}

/// A scale bar: two named targets (observed in markers.csv) a known distance apart.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleBarInput {
    /// Name of the first target.
    pub a: String,
    /// Name of the second target.
    pub b: String,
    /// Distance between their centres, metres.
    pub distance: f64,
    /// Standard deviation of the distance, metres, when given.
    pub sigma: Option<f64>,
    /// Line in the file.
    pub line: usize,
}

/// One data row: its fields and line number.
pub(crate) struct Row {
    pub(crate) fields: Vec<String>,
    pub(crate) line: usize,
}

/// Reads the rows of a CSV file, skipping comments, blank lines and a header equal (case-
/// insensitive) to one of `headers`; rows must have one of `counts` fields.
pub(crate) fn read_rows(
    path: &Path,
    headers: &[&[&str]],
    counts: &[usize],
    expected: &str,
) -> Result<Vec<Row>, IoError> {
    let text = fsutil::read_text(path)?;
    let mut rows = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(trimmed.as_bytes());
        let record = match reader.records().next() {
            Some(Ok(r)) => r,
            Some(Err(e)) => return Err(IoError::line(path, line, format!("malformed CSV: {e}"))),
            None => continue,
        };
        let fields: Vec<String> = record.iter().map(str::to_string).collect();
        if rows.is_empty()
            && headers.iter().any(|h| {
                h.len() == fields.len()
                    && h.iter()
                        .zip(&fields)
                        .all(|(a, b)| a.eq_ignore_ascii_case(b))
            })
        {
            continue;
        }
        if !counts.contains(&fields.len()) {
            return Err(IoError::line(
                path,
                line,
                format!("expected {expected}, found {} fields", fields.len()),
            ));
        }
        rows.push(Row { fields, line });
    }
    Ok(rows)
}

pub(crate) fn number(path: &Path, row: &Row, index: usize, column: &str) -> Result<f64, IoError> {
    let text = &row.fields[index];
    text.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| {
            IoError::line(
                path,
                row.line,
                format!("column `{column}`: expected a number, found \"{text}\""),
            )
        })
}

pub(crate) fn non_empty(
    path: &Path,
    row: &Row,
    index: usize,
    column: &str,
) -> Result<String, IoError> {
    let text = row.fields[index].clone();
    if text.is_empty() {
        return Err(IoError::line(
            path,
            row.line,
            format!("column `{column}` is empty"),
        ));
    }
    Ok(text)
}

/// A name not yet defined by an earlier row (`defined`: names and their lines).
fn defined_once<'a>(
    path: &Path,
    row: &Row,
    name: &str,
    mut defined: impl Iterator<Item = (&'a str, usize)>,
) -> Result<(), IoError> {
    match defined.find(|(n, _)| *n == name) {
        Some((_, line)) => Err(IoError::line(
            path,
            row.line,
            format!("point \"{name}\" is already defined on line {line}"),
        )),
        None => Ok(()),
    }
}

fn sigma(path: &Path, row: &Row) -> Result<Option<(f64, f64)>, IoError> {
    if row.fields.len() < 6 {
        return Ok(None);
    }
    let sxy = number(path, row, 4, "sxy")?;
    let sz = number(path, row, 5, "sz")?;
    if !(sxy > 0.0 && sz > 0.0) {
        return Err(IoError::line(
            path,
            row.line,
            "standard deviations sxy and sz must be positive",
        ));
    }
    Ok(Some((sxy, sz)))
}

fn xyz(path: &Path, row: &Row) -> Result<Vector3<f64>, IoError> {
    Ok(Vector3::new(
        number(path, row, 1, "x")?,
        number(path, row, 2, "y")?,
        number(path, row, 3, "z")?,
    ))
}

fn control_points(path: &Path, with_sigma: bool) -> Result<Vec<ControlPoint>, IoError> {
    let (counts, expected): (&[usize], _) = if with_sigma {
        (&[4, 6], "4 fields (name,x,y,z) or 6 (name,x,y,z,sxy,sz)")
    } else {
        (&[4], "4 fields (name,x,y,z)")
    };
    let rows = read_rows(
        path,
        &[
            &["name", "x", "y", "z"],
            &["name", "x", "y", "z", "sxy", "sz"],
        ],
        counts,
        expected,
    )?;
    let mut points: Vec<ControlPoint> = Vec::with_capacity(rows.len());
    for row in &rows {
        let name = non_empty(path, row, 0, "name")?;
        defined_once(
            path,
            row,
            &name,
            points.iter().map(|p| (p.name.as_str(), p.line)),
        )?;
        points.push(ControlPoint {
            name,
            position: xyz(path, row)?,
            sigma: sigma(path, row)?,
            line: row.line,
        });
    }
    Ok(points)
}

/// Reads `gcps.csv`: `name,x,y,z[,sxy,sz]`.
pub fn read_gcps(path: &Path) -> Result<Vec<ControlPoint>, IoError> {
    control_points(path, true)
}

/// Reads `checkpoints.csv`: `name,x,y,z`.
pub fn read_checkpoints(path: &Path) -> Result<Vec<ControlPoint>, IoError> {
    control_points(path, false)
}

/// Reads `stable_points.csv`: `name[,sxy,sz]`.
pub fn read_stable_points(path: &Path) -> Result<Vec<StablePointInput>, IoError> {
    let rows = read_rows(
        path,
        &[&["name"], &["name", "sxy", "sz"]],
        &[1, 3],
        "1 field (name) or 3 (name,sxy,sz)",
    )?;
    let mut points: Vec<StablePointInput> = Vec::with_capacity(rows.len());
    for row in &rows {
        let name = non_empty(path, row, 0, "name")?;
        defined_once(
            path,
            row,
            &name,
            points.iter().map(|p| (p.name.as_str(), p.line)),
        )?;
        let sigma = if row.fields.len() == 3 {
            let sxy = number(path, row, 1, "sxy")?;
            let sz = number(path, row, 2, "sz")?;
            if !(sxy >= 0.0 && sz >= 0.0) {
                return Err(IoError::line(
                    path,
                    row.line,
                    "standard deviations sxy and sz must not be negative",
                ));
            }
            Some((sxy, sz))
        } else {
            None
        };
        points.push(StablePointInput {
            name,
            sigma,
            line: row.line,
        });
    }
    Ok(points)
}

/// Reads `markers.csv`: `image,name,u,v`.
pub fn read_markers(path: &Path) -> Result<Vec<Marker>, IoError> {
    let rows = read_rows(
        path,
        &[&["image", "name", "u", "v"]],
        &[4],
        "4 fields (image,name,u,v)",
    )?;
    let mut markers = Vec::with_capacity(rows.len());
    for row in &rows {
        let marker = Marker {
            image: non_empty(path, row, 0, "image")?,
            name: non_empty(path, row, 1, "name")?,
            pixel: Vector2::new(number(path, row, 2, "u")?, number(path, row, 3, "v")?),
            line: row.line,
        };
        if let Some(dup) = markers
            .iter()
            .find(|m: &&Marker| m.image == marker.image && m.name == marker.name)
        {
            return Err(IoError::line(
                path,
                row.line,
                format!(
                    "point \"{}\" in image \"{}\" is already measured on line {}",
                    marker.name, marker.image, dup.line
                ),
            ));
        }
        markers.push(marker);
    }
    Ok(markers)
}

/// A fiducial mark measured by hand in a scan (`fiducials.csv`).
#[derive(Debug, Clone, PartialEq)]
pub struct FiducialMeasurement {
    /// Image path relative to the project directory.
    pub image: String,
    /// Mark name (as in the camera's `[camera.fiducials]`).
    pub mark: String,
    /// Pixel position in the scan (docs/design.md convention).
    pub pixel: Vector2<f64>,
    /// Line in the file.
    pub line: usize,
}

/// Reads `fiducials.csv`: `image,mark,u,v` — fiducial marks measured by hand in scans, pixels.
/// A fifth column (`residual_px`, as `timesift fiducials` writes in `out/fiducials.csv`) is
/// accepted and ignored, so that a corrected copy of that file can be given back.
pub fn read_fiducials(path: &Path) -> Result<Vec<FiducialMeasurement>, IoError> {
    let rows = read_rows(
        path,
        &[
            &["image", "mark", "u", "v"],
            &["image", "mark", "u", "v", "residual_px"],
        ],
        &[4, 5],
        "4 fields (image,mark,u,v)",
    )?;
    let mut marks: Vec<FiducialMeasurement> = Vec::with_capacity(rows.len());
    for row in &rows {
        let mark = FiducialMeasurement {
            image: non_empty(path, row, 0, "image")?,
            mark: non_empty(path, row, 1, "mark")?,
            pixel: Vector2::new(number(path, row, 2, "u")?, number(path, row, 3, "v")?),
            line: row.line,
        };
        if let Some(dup) = marks
            .iter()
            .find(|m| m.image == mark.image && m.mark == mark.mark)
        {
            return Err(IoError::line(
                path,
                row.line,
                format!(
                    "mark \"{}\" in image \"{}\" is already measured on line {}",
                    mark.mark, mark.image, dup.line
                ),
            ));
        }
        marks.push(mark);
    }
    Ok(marks)
}

/// Reads `scalebars.csv`: `a,b,distance[,sd]` (target names, metres).
pub fn read_scale_bars(path: &Path) -> Result<Vec<ScaleBarInput>, IoError> {
    let rows = read_rows(
        path,
        &[&["a", "b", "distance"], &["a", "b", "distance", "sd"]],
        &[3, 4],
        "3 fields (a,b,distance) or 4 (a,b,distance,sd)",
    )?;
    let mut bars = Vec::with_capacity(rows.len());
    for row in &rows {
        let (a, b) = (non_empty(path, row, 0, "a")?, non_empty(path, row, 1, "b")?);
        if a == b {
            return Err(IoError::line(
                path,
                row.line,
                format!("a scale bar needs two different targets, found \"{a}\" twice"),
            ));
        }
        let distance = number(path, row, 2, "distance")?;
        if distance <= 0.0 {
            return Err(IoError::line(
                path,
                row.line,
                "column `distance` must be positive",
            ));
        }
        let sigma = match row.fields.len() {
            4 => {
                let sd = number(path, row, 3, "sd")?;
                if sd <= 0.0 {
                    return Err(IoError::line(
                        path,
                        row.line,
                        "column `sd` must be positive",
                    ));
                }
                Some(sd)
            }
            _ => None,
        };
        bars.push(ScaleBarInput {
            a,
            b,
            distance,
            sigma,
            line: row.line,
        });
    }
    Ok(bars)
}

/// Reads `gnss.csv`: `image,x,y,z[,sxy,sz]`.
pub fn read_gnss(path: &Path) -> Result<Vec<GnssPrior>, IoError> {
    let rows = read_rows(
        path,
        &[
            &["image", "x", "y", "z"],
            &["image", "x", "y", "z", "sxy", "sz"],
        ],
        &[4, 6],
        "4 fields (image,x,y,z) or 6 (image,x,y,z,sxy,sz)",
    )?;
    let mut priors: Vec<GnssPrior> = Vec::with_capacity(rows.len());
    for row in &rows {
        let image = non_empty(path, row, 0, "image")?;
        if let Some(first) = priors.iter().find(|p| p.image == image) {
            return Err(IoError::line(
                path,
                row.line,
                format!(
                    "image \"{image}\" already has a prior on line {}",
                    first.line
                ),
            ));
        }
        priors.push(GnssPrior {
            image,
            position: xyz(path, row)?,
            sigma: sigma(path, row)?,
            line: row.line,
        });
    }
    Ok(priors)
}

/// Byte offset of the WKT keyword: the first `MULTIPOLYGON` or `POLYGON` followed (after spaces
/// and an optional `Z`/`M`/`ZM`) by `(`, so names containing the word are not mistaken for it.
fn geometry_start(upper: &str) -> Option<usize> {
    let mut from = 0;
    while let Some(rel) = upper[from..].find("POLYGON") {
        let at = from + rel;
        // Compared as bytes: five bytes back may fall inside a character of a name.
        let start = if at >= 5 && &upper.as_bytes()[at - 5..at] == b"MULTI" {
            at - 5
        } else {
            at
        };
        let rest = upper[at + "POLYGON".len()..].trim_start();
        let rest = rest
            .strip_prefix("ZM")
            .or_else(|| rest.strip_prefix('Z'))
            .or_else(|| rest.strip_prefix('M'))
            .unwrap_or(rest)
            .trim_start();
        if rest.starts_with('(') {
            return Some(start);
        }
        from = at + "POLYGON".len();
    }
    None
}

/// Reads `stable.csv`: one stable area per line, `[name,]WKT`, where the WKT (`POLYGON` or
/// `MULTIPOLYGON`) may be quoted or not (its commas are part of the geometry).
pub fn read_stable_areas(path: &Path) -> Result<Vec<StableArea>, IoError> {
    let text = fsutil::read_text(path)?;
    let mut areas = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let upper = trimmed.to_ascii_uppercase();
        let Some(start) = geometry_start(&upper) else {
            let is_header =
                areas.is_empty() && (upper.replace(' ', "") == "NAME,WKT" || upper == "WKT");
            if is_header {
                continue;
            }
            return Err(IoError::line(
                path,
                line,
                "expected [name,]POLYGON(...) or [name,]MULTIPOLYGON(...)",
            ));
        };
        let name = trimmed[..start]
            .trim()
            .trim_end_matches('"')
            .trim()
            .trim_end_matches(',')
            .trim()
            .trim_matches('"')
            .to_string();
        let geometry = trimmed[start..].trim().trim_end_matches('"');
        let polygons =
            parse_polygons(geometry).map_err(|message| IoError::line(path, line, message))?;
        areas.push(StableArea {
            name: (!name.is_empty()).then_some(name),
            polygons,
            line,
        });
    }
    Ok(areas)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn gcps_with_header_comments_and_sigmas() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "gcps.csv",
            "name,x,y,z,sxy,sz\n# surveyed 2018\nG1, 500000.5, 6000000.25, 12.5, 0.02, 0.03\n\nG2,1,2,3,0.1,0.2\n",
        );
        let g = read_gcps(&p).unwrap();
        assert_eq!(g.len(), 2);
        assert_eq!(g[0].name, "G1");
        assert_eq!(g[0].position, Vector3::new(500000.5, 6000000.25, 12.5));
        assert_eq!(g[0].sigma, Some((0.02, 0.03)));
        assert_eq!(g[1].line, 5);
    }

    #[test]
    fn wrong_field_count_names_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "gcps.csv", "G1,1,2,3\nG2,1,2\n");
        let e = read_gcps(&p).unwrap_err().to_string();
        assert!(
            e.contains("gcps.csv") && e.contains("line 2") && e.contains("3 fields"),
            "{e}"
        );
        let p = write(dir.path(), "markers.csv", "a.jpg,G1,10,20\na.jpg,G2,10\n");
        let e = read_markers(&p).unwrap_err().to_string();
        assert!(e.contains("markers.csv: line 2"), "{e}");
        let p = write(dir.path(), "checkpoints.csv", "C1,1,2,3,0.1,0.1\n");
        let e = read_checkpoints(&p).unwrap_err().to_string();
        assert!(e.contains("checkpoints.csv: line 1"), "{e}");
    }

    #[test]
    fn stable_points_with_and_without_stability() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "stable_points.csv",
            "name,sxy,sz\nboulder corner,0.01,0.02\n# the bridge\npier\n",
        );
        let points = read_stable_points(&p).unwrap();
        assert_eq!(points.len(), 2);
        assert_eq!(points[0].name, "boulder corner");
        assert_eq!(points[0].sigma, Some((0.01, 0.02)));
        assert_eq!((points[1].name.as_str(), points[1].sigma), ("pier", None));
        assert_eq!(points[1].line, 4);
        for (text, expected) in [
            (
                "a,1\n",
                "line 1: expected 1 field (name) or 3 (name,sxy,sz), found 2",
            ),
            ("a\na\n", "line 2: point \"a\" is already defined on line 1"),
            (
                "a,0.1,-1\n",
                "line 1: standard deviations sxy and sz must not be negative",
            ),
            ("a,x,1\n", "line 1: column `sxy`: expected a number"),
        ] {
            let p = write(dir.path(), "stable_points.csv", text);
            let e = read_stable_points(&p).unwrap_err().to_string();
            assert!(
                e.contains("stable_points.csv") && e.contains(expected),
                "{text:?}: {e}"
            );
        }
    }

    #[test]
    fn bad_numbers_and_duplicates_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "gnss.csv", "a.jpg,1,two,3\n");
        let e = read_gnss(&p).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("`y`"), "{e}");
        let p = write(dir.path(), "gcps.csv", "G1,1,2,3\nG1,4,5,6\n");
        assert!(read_gcps(&p).unwrap_err().to_string().contains("line 2"));
        let p = write(dir.path(), "gnss.csv", "a.jpg,1,2,3,0,1\n");
        assert!(read_gnss(&p).unwrap_err().to_string().contains("positive"));
    }

    #[test]
    fn scale_bars_with_and_without_sd() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "scalebars.csv",
            "a,b,distance,sd\nSB1a,SB1b,0.6,0.0002\nSB2a,SB2b,0.5\n",
        );
        let bars = read_scale_bars(&p).unwrap();
        assert_eq!(bars.len(), 2);
        assert_eq!((bars[0].a.as_str(), bars[0].distance), ("SB1a", 0.6));
        assert_eq!((bars[0].sigma, bars[1].sigma), (Some(0.0002), None));
        for bad in ["A,A,1\n", "A,B,-1\n", "A,B,1,0\n", "A,B\n"] {
            let p = write(dir.path(), "scalebars.csv", bad);
            let e = read_scale_bars(&p).unwrap_err().to_string();
            assert!(e.contains("scalebars.csv: line 1"), "{e}");
        }
    }

    #[test]
    fn stable_areas_quoted_or_not() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "stable.csv",
            "name,wkt\nrock,\"POLYGON ((0 0, 1 0, 1 1, 0 0))\"\nPOLYGON ((5 5, 6 5, 6 6, 5 5))\nroad,MULTIPOLYGON (((0 0, 1 0, 1 1)),((2 2, 3 2, 3 3)))\npolygon rock,POLYGON Z ((0 0 1, 1 0 1, 1 1 1))\n",
        );
        let s = read_stable_areas(&p).unwrap();
        assert_eq!(s.len(), 4);
        assert_eq!(s[0].name.as_deref(), Some("rock"));
        assert_eq!(s[3].name.as_deref(), Some("polygon rock"));
        assert_eq!(s[1].name, None);
        assert_eq!(s[2].polygons.len(), 2);
        let p = write(dir.path(), "stable.csv", "rock,LINESTRING (0 0, 1 1)\n");
        assert!(
            read_stable_areas(&p)
                .unwrap_err()
                .to_string()
                .contains("line 1")
        );
    }
}
