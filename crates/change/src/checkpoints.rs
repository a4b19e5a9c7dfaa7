//! Check-point residuals: measured minus reference coordinates per named point (dE, dN, dH), and
//! DEM heights at check points (dH only), with the summary statistics users publish.

use serde::{Deserialize, Serialize};

use crate::grid::Dem;
use crate::stats::{Statistics, statistics};

/// Residual of one check point (measured − reference), m. `d_east`/`d_north` are NaN when only a
/// height was measured (a DEM).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckPointResidual {
    /// Point name.
    pub name: String,
    /// East residual (NaN, written `null`, for DEM heights).
    #[serde(deserialize_with = "nan_if_null")]
    pub d_east: f64,
    /// North residual.
    #[serde(deserialize_with = "nan_if_null")]
    pub d_north: f64,
    /// Height residual.
    #[serde(deserialize_with = "nan_if_null")]
    pub d_height: f64,
}

/// JSON has no NaN: serde_json writes it as `null`, read back here as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Residuals and their statistics per component.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckPointReport {
    /// One entry per point that could be evaluated.
    pub points: Vec<CheckPointResidual>,
    /// Reference points that could not be evaluated (outside the DEM, nodata, not measured).
    pub missing: Vec<String>,
    /// Statistics of dE (None for DEM heights).
    pub east: Option<Statistics>,
    /// Statistics of dN.
    pub north: Option<Statistics>,
    /// Statistics of dH.
    pub height: Option<Statistics>,
    /// Horizontal RMSE, sqrt(RMSE_E² + RMSE_N²).
    pub horizontal_rmse: Option<f64>,
}

fn report(points: Vec<CheckPointResidual>, missing: Vec<String>) -> CheckPointReport {
    let east = statistics(points.iter().map(|p| p.d_east));
    let north = statistics(points.iter().map(|p| p.d_north));
    let height = statistics(points.iter().map(|p| p.d_height));
    let horizontal_rmse = match (&east, &north) {
        (Some(e), Some(n)) => Some(e.rmse.hypot(n.rmse)),
        _ => None,
    };
    CheckPointReport {
        points,
        missing,
        east,
        north,
        height,
        horizontal_rmse,
    }
}

/// Residuals of measured positions against reference positions, matched by name.
pub fn point_residuals(
    measured: &[(String, [f64; 3])],
    reference: &[(String, [f64; 3])],
) -> CheckPointReport {
    let mut points = Vec::new();
    let mut missing = Vec::new();
    for (name, r) in reference {
        match measured.iter().find(|(n, _)| n == name) {
            Some((_, m)) => points.push(CheckPointResidual {
                name: name.clone(),
                d_east: m[0] - r[0],
                d_north: m[1] - r[1],
                d_height: m[2] - r[2],
            }),
            None => missing.push(name.clone()),
        }
    }
    report(points, missing)
}

/// DEM height (bilinear) minus the check point's height, for every check point on the DEM.
pub fn dem_residuals(dem: &Dem, reference: &[(String, [f64; 3])]) -> CheckPointReport {
    let mut points = Vec::new();
    let mut missing = Vec::new();
    for (name, r) in reference {
        let z = dem.bilinear(r[0], r[1]);
        if z.is_nan() {
            missing.push(name.clone());
        } else {
            points.push(CheckPointResidual {
                name: name.clone(),
                d_east: f64::NAN,
                d_north: f64::NAN,
                d_height: z - r[2],
            });
        }
    }
    report(points, missing)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    #[test]
    fn dem_height_residuals_survive_json() {
        let r = CheckPointResidual {
            name: "CHK1".into(),
            d_east: f64::NAN,
            d_north: f64::NAN,
            d_height: -0.25,
        };
        let text = serde_json::to_string(&r).expect("json");
        assert!(text.contains("\"d_east\":null"), "{text}");
        let back: CheckPointResidual = serde_json::from_str(&text).expect("read back");
        assert!(back.d_east.is_nan() && back.d_north.is_nan() && back.d_height == -0.25);
    }

    #[test]
    fn residuals_by_name_and_on_a_dem() {
        let reference = vec![
            ("a".to_string(), [10.0, 20.0, 5.0]),
            ("b".to_string(), [12.0, 18.0, 6.0]),
            ("c".to_string(), [500.0, 500.0, 6.0]),
        ];
        let measured = vec![
            ("b".to_string(), [12.3, 17.6, 6.1]),
            ("a".to_string(), [10.0, 20.0, 4.9]),
        ];
        let r = point_residuals(&measured, &reference);
        assert_eq!(r.missing, vec!["c".to_string()]);
        assert!(
            (r.points[1].d_east - 0.3).abs() < 1e-12 && (r.points[1].d_north + 0.4).abs() < 1e-12
        );
        let e = r.east.expect("east");
        assert!((e.rmse - (0.09f64 / 2.0).sqrt()).abs() < 1e-12);
        assert!((r.horizontal_rmse.expect("h") - ((0.09 + 0.16) / 2.0f64).sqrt()).abs() < 1e-12);

        let grid = Grid {
            transform: GeoTransform {
                origin_x: 0.0,
                origin_y: 40.0,
                pixel_width: 1.0,
                pixel_height: -1.0,
            },
            width: 40,
            height: 40,
            crs: Crs::Local,
        };
        let values = (0..grid.len())
            .map(|i| {
                let (x, y) = grid.cell_center(i % 40, i / 40);
                (0.1 * x + 0.05 * y) as f32
            })
            .collect();
        let r = dem_residuals(&Dem { grid, values }, &reference);
        // DEM at a: 1 + 1 = 2 → 2 − 5; at b: 1.2 + 0.9 = 2.1 → 2.1 − 6.
        assert!(
            (r.points[0].d_height + 3.0).abs() < 1e-5 && (r.points[1].d_height + 3.9).abs() < 1e-5
        );
        assert!(r.east.is_none() && r.missing == vec!["c".to_string()]);
    }
}
