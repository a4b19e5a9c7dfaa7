//! The analysis of one DEM pair, as every caller needs it: optional co-registration of the later
//! DEM on the stable areas, the DEM of difference, statistics over every cell and over the stable
//! areas, the stable-area plane, the level of detection with where it came from, volumes with
//! their uncertainty (every cell, and only cells beyond the LoD) and the count of significant
//! cells.
//!
//! Why one function: the choices in it — which σ makes the LoD, which σ goes into the volume
//! uncertainty, when a co-registration is suspicious — are the method. The command line, the
//! `change` stage, the demo and the benches must make them the same way, so they live here and the
//! callers only read and write files.

use crate::ChangeError;
use crate::correlation::{Variogram, variogram};
use crate::dod::dem_of_difference;
use crate::grid::{Dem, check_same_crs};
use crate::mask::Mask;
use crate::nuth_kaab::{NuthKaabOptions, NuthKaabResult, nuth_kaab};
use crate::stats::{Statistics, statistics};
use crate::trend::{PlaneTrend, plane_trend};
use crate::volume::{VolumeOptions, Volumes, lod95, significance, volumes};

/// How a DEM pair is analysed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PairOptions {
    /// Co-registration of the later DEM onto the earlier one (Nuth & Kääb), or none. Time-SIFT's
    /// DEMs stack without it; it is there to compare with the strategies that need it.
    pub coregistration: Option<NuthKaabOptions>,
    /// σ of each DEM (m) when the user knows them; otherwise the LoD and the volume uncertainty
    /// come from the stable areas' spread.
    pub sigmas: Option<(f64, f64)>,
}

/// Where the level of detection came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LodSource {
    /// `1.96 · sqrt(σa² + σb²)` from the σ the user gave.
    Sigmas,
    /// `1.96 · NMAD` of the difference over the stable areas: that spread already holds both
    /// DEMs' errors.
    StableNmad,
    /// No stable area and no σ: there is no LoD.
    None,
}

impl std::fmt::Display for LodSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LodSource::Sigmas => "sigmas given",
            LodSource::StableNmad => "1.96 × stable-area NMAD of the difference",
            LodSource::None => "none (no stable area and no sigma given)",
        })
    }
}

/// The level of detection of a pair and where it came from: the σ given win over the stable
/// areas' NMAD; with neither there is none.
pub fn level_of_detection(
    sigmas: Option<(f64, f64)>,
    stable: Option<&Statistics>,
) -> (Option<f64>, LodSource) {
    match (sigmas, stable) {
        (Some((sa, sb)), _) => (Some(lod95(sa, sb)), LodSource::Sigmas),
        (None, Some(s)) => (Some(1.96 * s.nmad), LodSource::StableNmad),
        (None, None) => (None, LodSource::None),
    }
}

/// The uncertainty of the volumes: the random σ from the σ given (both DEMs in quadrature) or the
/// stable areas' NMAD, correlated between cells as the stable areas' variogram says (when there
/// is one); the systematic σ is the stable areas' median offset whenever there are stable areas
/// (a bias the σ given cannot know of), else 0.
pub fn volume_uncertainty(
    sigmas: Option<(f64, f64)>,
    stable: Option<&Statistics>,
    stable_variogram: Option<&Variogram>,
) -> VolumeOptions {
    let options = match (sigmas, stable) {
        (Some((sa, sb)), _) => VolumeOptions {
            threshold: 0.0,
            sigma_random: sa.hypot(sb),
            sigma_systematic: stable.map_or(0.0, |s| s.median.abs()),
            correlation: None,
        },
        (None, Some(s)) => VolumeOptions::from_stable(s),
        (None, None) => VolumeOptions::default(),
    };
    VolumeOptions {
        correlation: stable_variogram.map(Variogram::correlation),
        ..options
    }
}

/// Everything found about a DEM pair.
#[derive(Debug, Clone)]
pub struct PairAnalysis {
    /// The co-registration applied to the later DEM, when asked for.
    pub coregistration: Option<NuthKaabResult>,
    /// The later DEM as differenced: moved by the co-registration when there was one.
    pub later: Dem,
    /// Later minus earlier, on the cells both cover.
    pub dod: Dem,
    /// Statistics of the difference over every cell.
    pub all: Statistics,
    /// Statistics over the stable areas.
    pub stable: Option<Statistics>,
    /// The least-squares plane of the difference over the stable areas.
    pub stable_trend: Option<PlaneTrend>,
    /// The variogram of the difference over the stable areas: how its errors correlate, which
    /// the volume uncertainty follows.
    pub stable_variogram: Option<Variogram>,
    /// 95 % level of detection, m.
    pub lod95: Option<f64>,
    /// Where it came from.
    pub lod_source: LodSource,
    /// Cells with |dz| > LoD95.
    pub significant_cells: Option<usize>,
    /// Volumes over the region, every cell counted.
    pub volumes: Volumes,
    /// Volumes counting only cells beyond the LoD.
    pub volumes_beyond_lod: Option<Volumes>,
    /// What the user should know: co-registration without stable areas, one that did not lower
    /// the stable NMAD or did not converge, a stable area too small or too thin for a plane.
    pub warnings: Vec<String>,
}

impl PairAnalysis {
    /// Per-cell significance flags of the DoD (1 beyond the LoD, 0 within, 255 nodata), when
    /// there is a LoD.
    pub fn significance(&self) -> Option<Vec<u8>> {
        self.lod95.map(|l| significance(&self.dod, l))
    }
}

/// Analyses `later − earlier`. `stable` and `region` are masks on any grid of the same CRS (they
/// are carried onto the DoD's cells); `region` limits the volumes (every cell when `None`).
///
/// Errors: different CRSs, no cell valid in both DEMs, a stable mask with no valid cell of the
/// difference, a co-registration that fails, invalid options.
pub fn analyse_pair(
    earlier: &Dem,
    later: &Dem,
    stable: Option<&Mask>,
    region: Option<&Mask>,
    options: &PairOptions,
) -> Result<PairAnalysis, ChangeError> {
    check_same_crs(earlier.grid.crs, later.grid.crs)?;
    let mut warnings = Vec::new();
    let coregistration = coregister(earlier, later, stable, options, &mut warnings)?;
    let later = match &coregistration {
        Some(r) => r.apply(later),
        None => later.clone(),
    };
    let dod = dem_of_difference(earlier, &later)?;
    let values = || dod.values.iter().map(|&v| v as f64);
    let all = statistics(values())
        .ok_or_else(|| ChangeError::NoOverlap("no cell holds a height in both DEMs".into()))?;
    let stable_on_dod = match stable {
        Some(m) => Some(m.onto(&dod.grid)?),
        None => None,
    };
    let stable_stats = match &stable_on_dod {
        Some(m) => Some(
            statistics(values().zip(&m.cells).filter(|(_, s)| **s).map(|(v, _)| v)).ok_or_else(
                || ChangeError::EmptyStable("no stable cell holds a height in both DEMs".into()),
            )?,
        ),
        None => None,
    };
    let stable_trend = stable_on_dod
        .as_ref()
        .and_then(|m| stable_plane(&dod, m, &mut warnings));
    let stable_variogram = stable_on_dod
        .as_ref()
        .and_then(|m| stable_correlation(&dod, m, &mut warnings));
    let (lod, lod_source) = level_of_detection(options.sigmas, stable_stats.as_ref());
    let region = match region {
        Some(m) => Some(m.onto(&dod.grid)?),
        None => None,
    };
    let uncertainty = volume_uncertainty(
        options.sigmas,
        stable_stats.as_ref(),
        stable_variogram.as_ref(),
    );
    let (every_cell, beyond_lod) = pair_volumes(&dod, region.as_ref(), uncertainty, lod)?;
    let significant_cells = lod.map(|l| significance(&dod, l).iter().filter(|&&f| f == 1).count());
    Ok(PairAnalysis {
        coregistration,
        later,
        dod,
        all,
        stable: stable_stats,
        stable_trend,
        stable_variogram,
        lod95: lod,
        lod_source,
        significant_cells,
        volumes: every_cell,
        volumes_beyond_lod: beyond_lod,
        warnings,
    })
}

/// The co-registration of `later` onto `earlier` when the options ask for one, with the warnings
/// it calls for: no stable areas, a stable NMAD it did not lower, no convergence.
fn coregister(
    earlier: &Dem,
    later: &Dem,
    stable: Option<&Mask>,
    options: &PairOptions,
    warnings: &mut Vec<String>,
) -> Result<Option<NuthKaabResult>, ChangeError> {
    if stable.is_none() && options.coregistration.is_some() {
        warnings.push(
            "co-registration used every cell: without stable areas, real change biases the shift"
                .to_string(),
        );
    }
    let coregistration = match &options.coregistration {
        Some(nk) => Some(nuth_kaab(earlier, later, stable, nk)?),
        None => None,
    };
    if let Some(r) = &coregistration {
        if !(r.nmad_after < r.nmad_before) {
            warnings.push(format!(
                "co-registration did not lower the stable-area NMAD ({:.4} → {:.4} m): the DEMs \
                 were probably aligned already, or the stable areas changed",
                r.nmad_before, r.nmad_after
            ));
        }
        if !r.converged {
            warnings.push("co-registration stopped at its iteration limit".to_string());
        }
    }
    Ok(coregistration)
}

/// The least-squares plane of the difference over the stable areas, or a warning saying why
/// there is none.
fn stable_plane(dod: &Dem, stable: &Mask, warnings: &mut Vec<String>) -> Option<PlaneTrend> {
    match plane_trend(dod, Some(stable)) {
        Ok(t) => Some(t),
        Err(e) => {
            warnings.push(format!("no plane through the stable areas: {e}"));
            None
        }
    }
}

/// The variogram of the difference over the stable areas, or a warning that the volume
/// uncertainties will assume independent cells.
fn stable_correlation(dod: &Dem, stable: &Mask, warnings: &mut Vec<String>) -> Option<Variogram> {
    match variogram(dod, Some(stable)) {
        Ok(v) => Some(v),
        Err(e) => {
            warnings.push(format!(
                "no variogram of the stable areas ({e}): volume uncertainties assume \
                 independent cells and are too small"
            ));
            None
        }
    }
}

/// The volumes over the region with every cell counted, and counting only the cells beyond the
/// LoD when there is one.
fn pair_volumes(
    dod: &Dem,
    region: Option<&Mask>,
    uncertainty: VolumeOptions,
    lod: Option<f64>,
) -> Result<(Volumes, Option<Volumes>), ChangeError> {
    let every_cell = volumes(dod, region, uncertainty)?;
    let beyond_lod = match lod {
        Some(l) => Some(volumes(
            dod,
            region,
            VolumeOptions {
                threshold: l,
                ..uncertainty
            },
        )?),
        None => None,
    };
    Ok((every_cell, beyond_lod))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    fn grid(n: usize, cell: f64) -> Grid {
        Grid {
            transform: GeoTransform {
                origin_x: 0.0,
                origin_y: n as f64 * cell,
                pixel_width: cell,
                pixel_height: -cell,
            },
            width: n,
            height: n,
            crs: Crs::Local,
        }
    }

    fn dem(grid: Grid, height: impl Fn(f64, f64) -> f64) -> Dem {
        let mut values = Vec::with_capacity(grid.len());
        for r in 0..grid.height {
            for c in 0..grid.width {
                let (x, y) = grid.cell_center(c, r);
                values.push(height(x, y) as f32);
            }
        }
        Dem { grid, values }
    }

    /// A 40 × 40 grid of 1 m cells; the later DEM is 0.5 m higher inside a 10 × 10 m square
    /// (x, y in 10..20) and has a deterministic ±`noise` pattern everywhere.
    fn pair(noise: f64) -> (Dem, Dem, Mask) {
        let g = grid(40, 1.0);
        let ground = |x: f64, y: f64| 100.0 + 0.1 * x + 0.05 * y;
        let earlier = dem(g, ground);
        let later = dem(g, |x, y| {
            let bump = if (10.0..20.0).contains(&x) && (10.0..20.0).contains(&y) {
                0.5
            } else {
                0.0
            };
            let sign = if ((x + y) as i64) % 2 == 0 { 1.0 } else { -1.0 };
            ground(x, y) + bump + sign * noise
        });
        let mut stable = Mask::all(g);
        for r in 0..g.height {
            for c in 0..g.width {
                let (x, _) = g.cell_center(c, r);
                stable.cells[r * g.width + c] = x >= 25.0;
            }
        }
        (earlier, later, stable)
    }

    #[test]
    fn exact_change_is_measured_exactly() {
        let (earlier, later, stable) = pair(0.0);
        let a = analyse_pair(
            &earlier,
            &later,
            Some(&stable),
            None,
            &PairOptions::default(),
        )
        .expect("analysis");
        // 100 cells of 1 m² raised by 0.5 m (f32 heights near 100 m: ~1e-5 m per cell).
        assert!((a.volumes.fill - 50.0).abs() < 1e-2, "{:?}", a.volumes);
        assert!(a.volumes.cut < 1e-2, "{:?}", a.volumes);
        let s = a.stable.expect("stable statistics");
        assert!(s.median.abs() < 1e-4 && s.nmad < 1e-4, "{s:?}");
        assert_eq!(a.lod_source, LodSource::StableNmad);
        assert_eq!(a.significant_cells, Some(100));
        let t = a.stable_trend.expect("plane");
        assert!(t.gain_m.abs() < 1e-3, "{t:?}");
        assert!(a.warnings.is_empty(), "{:?}", a.warnings);
    }

    #[test]
    fn lod_comes_from_the_stable_spread_and_sigmas_win() {
        let (earlier, later, stable) = pair(0.02);
        let a = analyse_pair(
            &earlier,
            &later,
            Some(&stable),
            None,
            &PairOptions::default(),
        )
        .expect("analysis");
        let nmad = a.stable.expect("stable").nmad;
        // ±0.02 m alternating: the NMAD is 1.4826 × 0.02.
        assert!((nmad - 1.4826 * 0.02).abs() < 1e-4, "{nmad}");
        assert!((a.lod95.expect("lod") - 1.96 * nmad).abs() < 1e-12);
        // Noise is below the LoD, the bump above it: exactly the bump's cells are significant.
        assert_eq!(a.significant_cells, Some(100));
        let b = analyse_pair(
            &earlier,
            &later,
            Some(&stable),
            None,
            &PairOptions {
                sigmas: Some((0.3, 0.4)),
                ..Default::default()
            },
        )
        .expect("analysis");
        assert_eq!(b.lod_source, LodSource::Sigmas);
        assert!((b.lod95.expect("lod") - 1.96 * 0.5).abs() < 1e-12);
        // A LoD of 0.98 m hides the 0.5 m bump.
        assert_eq!(b.significant_cells, Some(0));
        let none =
            analyse_pair(&earlier, &later, None, None, &PairOptions::default()).expect("analysis");
        assert_eq!((none.lod95, none.lod_source), (None, LodSource::None));
    }

    #[test]
    fn volume_uncertainty_follows_the_stable_area() {
        let s = statistics([0.1, -0.1, 0.3, 0.2, 0.2]).expect("statistics");
        let v = volume_uncertainty(None, Some(&s), None);
        assert_eq!(
            (v.sigma_random, v.sigma_systematic),
            (s.nmad, s.median.abs())
        );
        let v = volume_uncertainty(Some((0.3, 0.4)), Some(&s), None);
        assert!((v.sigma_random - 0.5).abs() < 1e-12);
        assert_eq!(v.sigma_systematic, s.median.abs());
        assert_eq!(
            volume_uncertainty(None, None, None),
            VolumeOptions::default()
        );
    }

    #[test]
    fn coregistration_without_stable_areas_is_named() {
        let (earlier, later, _) = pair(0.0);
        let a = analyse_pair(
            &earlier,
            &later,
            None,
            None,
            &PairOptions {
                coregistration: Some(NuthKaabOptions {
                    horizontal: false,
                    ..Default::default()
                }),
                ..Default::default()
            },
        )
        .expect("analysis");
        assert!(
            a.warnings
                .iter()
                .any(|w| w.contains("without stable areas"))
        );
        assert!(a.coregistration.is_some());
    }

    #[test]
    fn disjoint_dems_are_an_error() {
        let (earlier, _, _) = pair(0.0);
        let far = earlier.translated(1000.0, 0.0, 0.0);
        let e = analyse_pair(&earlier, &far, None, None, &PairOptions::default())
            .expect_err("no overlap");
        assert!(matches!(e, ChangeError::NoOverlap(_)), "{e}");
    }
}
