//! `cargo xtask bench coreg`: DoD-level co-registration on `../shared/data/rendered-mar`, two
//! real beach surveys rendered with exact truth, where the epochs share little ground that looks
//! alike. A copy of the project (the images linked, not copied) is run with the defaults and
//! with each variant asked for; then each epoch's DEM is compared with its true surface and the
//! DoD with the true DoD, over the truth's stable ground (`truth/stable_mask.tif`): the median
//! and the tilt of the plane fitted to the errors (mm/m), which check points along the corridor
//! cannot see, beside the check-point RMSE and the datum-tilt σ the align report predicts.
//! `truth` runs the products on the true cameras: the floor of what dense matching and gridding
//! allow. Each DoD has a second row, `land`, without the sea (stable cells whose true height is
//! below 1.5 m: the source's sea surface, held still and textured per epoch). Written as `coreg.md` and `coreg.json` in the output folder and printed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use timesift::Project;
use timesift::config::DenseConfig;
use timesift::report::{AlignReport, read_json};
use timesift::stages::{Stage, run, run_stage};
use timesift_change::grid::Dem;
use timesift_change::trend::{SurfaceAgreement, residual_plane};

/// What to run.
pub struct CoregBench {
    /// Variants by name (see [`VARIANTS`]).
    pub variants: Vec<String>,
    pub out: PathBuf,
    /// The default `[dense]` settings instead of `DenseConfig::quick`.
    pub full_dense: bool,
}

/// The variants: a name and the lines added to `[align]` of the project (`truth` is special:
/// the true cameras replace the align stage's).
pub const VARIANTS: [(&str, &str); 7] = [
    ("default", ""),
    ("joined", "join_epoch_ties = true"),
    ("guided", "guided_epoch_ties = true"),
    ("nosurface", "surface_ties = false"),
    (
        "b1",
        "self_calibration = [\"f\", \"cx\", \"cy\", \"b1\", \"k1\", \"k2\", \"k3\", \"p1\", \"p2\"]",
    ),
    ("gcps-all", "gcps_in_all_epochs = true"),
    ("truth", ""),
];

/// The ground sampling distance of each epoch of rendered-mar (its README), m.
const GSD: [(&str, f64); 2] = [("20180925", 0.354), ("20190205", 0.300)];
/// Below this true height the scene's stable ground is sea held still (its README: "mask the
/// sea"), textured by each epoch's orthophoto; a DoD row without it is printed too.
const SEA_LEVEL_M: f64 = 1.5;

/// One epoch's DEM, or one pair's DoD, against the truth over the stable ground.
#[derive(Debug, Clone, serde::Serialize)]
struct Agreement {
    /// An epoch, or `a__b` for a DoD.
    name: String,
    /// GSD the median is expressed in (the finer epoch's for a DoD), m.
    gsd_m: f64,
    /// Cells compared, median (m) and plane tilt of the errors.
    plane: Option<SurfaceAgreement>,
    /// NMAD of the errors, m.
    nmad_m: Option<f64>,
}

/// One variant's figures.
#[derive(Debug, Clone, serde::Serialize)]
struct VariantRow {
    variant: String,
    /// Per epoch: check-point RMSE (dE, dN, dH) from the align report, m.
    check_rmse_m: Vec<(String, Option<[f64; 3]>)>,
    /// Per epoch: inter-epoch tie points.
    inter_epoch_ties: Vec<(String, usize)>,
    /// Per epoch: the datum-tilt σ the report predicts from the control alone (largest,
    /// mm/m).
    predicted_tilt_sigma: Vec<(String, Option<f64>)>,
    /// Per epoch and per pair (`a__b`): the tilt σ from the block's covariance (largest, mm/m).
    block_tilt_sigma: Vec<(String, Option<f64>)>,
    /// Per epoch DEM and per DoD against the truth.
    surfaces: Vec<Agreement>,
    seconds: f64,
    error: Option<String>,
}

pub fn run_bench(bench: &CoregBench) -> anyhow::Result<()> {
    for v in &bench.variants {
        if !VARIANTS.iter().any(|(n, _)| n == v) {
            let names: Vec<&str> = VARIANTS.iter().map(|(n, _)| *n).collect();
            anyhow::bail!("--variants: unknown \"{v}\" ({})", names.join(", "));
        }
    }
    let source = crate::shared_data().join("rendered-mar");
    let dir = bench.out.join("rendered-mar");
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    copy_project(&source, &dir)?;
    let project = Project::load(&dir)?;
    let start = Instant::now();
    run(&project, Some(Stage::Features), Some(Stage::Match))?;
    println!(
        "rendered-mar: features and matches in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    let truth = Truth::read(&source.join("truth"))?;
    let mut rows = Vec::new();
    for variant in &bench.variants {
        let start = Instant::now();
        let result = run_variant(bench, &source, &dir, variant, &truth);
        let seconds = start.elapsed().as_secs_f64();
        let row = match result {
            Ok(mut row) => {
                row.seconds = seconds;
                row
            }
            Err(e) => VariantRow {
                variant: variant.clone(),
                check_rmse_m: Vec::new(),
                inter_epoch_ties: Vec::new(),
                predicted_tilt_sigma: Vec::new(),
                block_tilt_sigma: Vec::new(),
                surfaces: Vec::new(),
                seconds,
                error: Some(format!("{e:#}")),
            },
        };
        println!("{}", table(std::slice::from_ref(&row)));
        rows.push(row);
    }
    let dense = if bench.full_dense {
        DenseConfig::default()
    } else {
        DenseConfig::quick()
    };
    let markdown = format!(
        "rendered-mar, products with [dense] {} (--full-dense: the defaults).\n\n{}",
        dense.differences(),
        table(&rows)
    );
    println!("{markdown}");
    std::fs::write(bench.out.join("coreg.md"), &markdown)?;
    std::fs::write(
        bench.out.join("coreg.json"),
        serde_json::to_string_pretty(&rows)?,
    )?;
    println!("written: {}", bench.out.join("coreg.{md,json}").display());
    Ok(())
}

/// The project files of rendered-mar copied, its images linked.
pub(crate) fn copy_project(source: &Path, dir: &Path) -> anyhow::Result<()> {
    for name in [
        "project.toml",
        "gcps.csv",
        "checkpoints.csv",
        "gnss.csv",
        "markers.csv",
    ] {
        let to = dir.join(name);
        let _ = std::fs::remove_file(&to);
        std::fs::copy(source.join(name), &to).with_context(|| name.to_string())?;
        let mut permissions = std::fs::metadata(&to)?.permissions();
        #[allow(clippy::permissions_set_readonly_false)]
        permissions.set_readonly(false);
        std::fs::set_permissions(&to, permissions)?;
    }
    let images = dir.join("images");
    if !images.exists() {
        std::os::unix::fs::symlink(source.join("images").canonicalize()?, &images)?;
    }
    Ok(())
}

/// Runs one variant's align (or writes the true cameras), dense and dem stages and compares.
fn run_variant(
    bench: &CoregBench,
    source: &Path,
    dir: &Path,
    variant: &str,
    truth: &Truth,
) -> anyhow::Result<VariantRow> {
    let lines = VARIANTS
        .iter()
        .find(|(n, _)| *n == variant)
        .map_or("", |(_, l)| *l);
    let toml = std::fs::read_to_string(source.join("project.toml"))?;
    let toml = match lines.is_empty() {
        true => toml,
        false => toml.replacen("[align]\n", &format!("[align]\n{lines}\n"), 1),
    };
    std::fs::write(dir.join("project.toml"), toml)?;
    let mut project = Project::load(dir)?;
    if !bench.full_dense {
        project.config.dense = DenseConfig::quick();
    }
    let layout = project.layout();
    // The align stage runs for `truth` too: its sparse points bound the depth search.
    run_stage(&project, Stage::Align)?;
    let report: AlignReport = read_json(&layout.report_json())?;
    if variant == "truth" {
        std::fs::copy(source.join("truth/cameras.json"), layout.cameras_json())?;
    }
    for stage in [Stage::Dense, Stage::Dem] {
        run_stage(&project, stage)?;
    }
    let mut surfaces = Vec::new();
    // Per epoch, its DEM's errors on the stable ground; a DoD's are their differences.
    let mut errors = Vec::new();
    for epoch in &project.epochs {
        let name = epoch.name.as_str();
        let dem = Dem::from_raster(timesift_io::geotiff::read_f32(&layout.dem(name))?, None)?;
        let count = Dem::from_raster(
            timesift_io::geotiff::read_f32(&layout.dem_count(name))?,
            None,
        )?;
        let own = truth.errors(&dem, &count, name)?;
        surfaces.push(agreement(name, gsd_of(name), &own));
        errors.push((name.to_string(), own));
    }
    for pair in errors.windows(2) {
        let ((a, ea), (b, eb)) = (&pair[0], &pair[1]);
        // Cells measured in both (one lattice: equal centres, keyed to the millimetre): the
        // DoD's error is the difference of the two DEMs' errors.
        let key = |x: f64, y: f64| ((x * 1e3).round() as i64, (y * 1e3).round() as i64);
        let by_cell: std::collections::HashMap<(i64, i64), f64> =
            ea.iter().map(|&(x, y, e)| (key(x, y), e)).collect();
        let dod: Vec<(f64, f64, f64)> = eb
            .iter()
            .filter_map(|&(x, y, e)| {
                let a = by_cell.get(&key(x, y))?;
                Some((x, y, e - a))
            })
            .collect();
        surfaces.push(agreement(
            &format!("{a}__{b}"),
            gsd_of(a).min(gsd_of(b)),
            &dod,
        ));
        let land: Vec<(f64, f64, f64)> = dod
            .iter()
            .filter(|&&(x, y, _)| truth.height(a, x, y).is_some_and(|z| z > SEA_LEVEL_M))
            .copied()
            .collect();
        surfaces.push(agreement(
            &format!("{a}__{b} land"),
            gsd_of(a).min(gsd_of(b)),
            &land,
        ));
    }
    let epochs: Vec<_> = report.epochs.iter().collect();
    let row = VariantRow {
        variant: variant.to_string(),
        check_rmse_m: epochs
            .iter()
            .map(|(n, e)| {
                let rmse = e.check_points.rmse.as_ref().map(|r| [r.de, r.dn, r.dh]);
                (n.to_string(), rmse)
            })
            .collect(),
        inter_epoch_ties: epochs
            .iter()
            .map(|(n, e)| (n.to_string(), e.inter_epoch_tie_points))
            .collect(),
        predicted_tilt_sigma: epochs
            .iter()
            .map(|(n, e)| (n.to_string(), loosest(&e.datum_tilt)))
            .collect(),
        block_tilt_sigma: epochs
            .iter()
            .map(|(n, e)| (n.to_string(), loosest(&e.block_tilt)))
            .chain(report.epoch_pairs.iter().map(|p| {
                let name = format!("{}__{}", p.epochs[0], p.epochs[1]);
                (name, loosest(&p.dod_tilt))
            }))
            .collect(),
        surfaces,
        seconds: 0.0,
        error: None,
    };
    let kept = dir.join(format!("out-{variant}"));
    let _ = std::fs::remove_dir_all(&kept);
    std::fs::rename(layout.out_dir(), &kept)?;
    Ok(row)
}

/// A tilt σ about its loosest axis, mm/m.
fn loosest(tilt: &Option<timesift::report::DatumTiltReport>) -> Option<f64> {
    tilt.as_ref().map(|t| t.sigma_max_mm_per_m)
}

pub(crate) fn gsd_of(epoch: &str) -> f64 {
    GSD.iter()
        .find(|(e, _)| *e == epoch)
        .map_or(f64::NAN, |(_, g)| *g)
}

/// The median, plane and NMAD of height errors at points.
fn agreement(name: &str, gsd_m: f64, errors: &[(f64, f64, f64)]) -> Agreement {
    let nmad_m = timesift_change::stats::statistics(errors.iter().map(|e| e.2)).map(|s| s.nmad);
    Agreement {
        name: name.to_string(),
        gsd_m,
        plane: residual_plane(errors),
        nmad_m,
    }
}

/// rendered-mar's truth: the true surface of each epoch and the stable mask.
struct Truth {
    dems: Vec<(String, Dem)>,
    stable: Dem,
}

impl Truth {
    fn read(dir: &Path) -> anyhow::Result<Truth> {
        let mut dems = Vec::new();
        for (epoch, _) in GSD {
            let path = dir.join(format!("dem_{epoch}.tif"));
            let raster = timesift_io::geotiff::read_f32(&path)?;
            dems.push((epoch.to_string(), Dem::from_raster(raster, None)?));
        }
        let stable = Dem::from_raster(
            timesift_io::geotiff::read_f32(&dir.join("stable_mask.tif"))?,
            None,
        )?;
        Ok(Truth { dems, stable })
    }

    /// The true height of `epoch` at (x, y), where known.
    fn height(&self, epoch: &str, x: f64, y: f64) -> Option<f64> {
        let (_, dem) = self.dems.iter().find(|(e, _)| e == epoch)?;
        Some(dem.bilinear(x, y)).filter(|z| z.is_finite())
    }

    /// Height errors (DEM − the true surface of `epoch`) at the centres of the measured cells of
    /// `dem` on the stable ground (common to both epochs): `(x, y, error)`.
    fn errors(&self, dem: &Dem, count: &Dem, epoch: &str) -> anyhow::Result<Vec<(f64, f64, f64)>> {
        let truth = &self
            .dems
            .iter()
            .find(|(e, _)| e == epoch)
            .with_context(|| format!("no true DEM of {epoch}"))?
            .1;
        let mut errors = Vec::new();
        for r in 0..dem.grid.height {
            for c in 0..dem.grid.width {
                let h = dem.get(c, r);
                if !h.is_finite() || !(count.get(c, r) > 0.0) {
                    continue;
                }
                let (x, y) = dem.grid.cell_center(c, r);
                let (fc, fr) = self.stable.grid.continuous_index(x, y);
                let (sc, sr) = (fc.floor(), fr.floor());
                let stable = sc >= 0.0
                    && sr >= 0.0
                    && (sc as usize) < self.stable.grid.width
                    && (sr as usize) < self.stable.grid.height
                    && self.stable.get(sc as usize, sr as usize) == 1.0;
                if !stable {
                    continue;
                }
                let z = truth.bilinear(x, y);
                if z.is_finite() {
                    errors.push((x, y, h as f64 - z));
                }
            }
        }
        Ok(errors)
    }
}

fn cell(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".to_string(), |v| format!("{v:.digits$}"))
}

/// The rows as a markdown table: one line per epoch and per DoD of each variant.
fn table(rows: &[VariantRow]) -> String {
    let mut s = String::from(
        "| variant | surface | check RMSE dE/dN/dH m | inter-epoch ties | tilt σ mm/m: control / block \
         | stable cells | median m (GSD) | tilt mm/m (σ of block) | NMAD m | s |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
    );
    for row in rows {
        if let Some(e) = &row.error {
            s.push_str(&format!(
                "| {} | failed: {e} | | | | | | | | {:.0} |\n",
                row.variant, row.seconds
            ));
            continue;
        }
        for a in &row.surfaces {
            let of = |list: &[(String, Option<f64>)]| {
                list.iter()
                    .find(|(n, _)| *n == a.name)
                    .and_then(|(_, v)| *v)
            };
            let check = row
                .check_rmse_m
                .iter()
                .find(|(n, _)| *n == a.name)
                .and_then(|(_, v)| *v);
            let ties = row
                .inter_epoch_ties
                .iter()
                .find(|(n, _)| *n == a.name)
                .map(|(_, t)| t.to_string());
            let plane = a.plane.as_ref();
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} / {} | {} | {} ({}) | {} ({}) | {} | {:.0} |\n",
                row.variant,
                a.name,
                timesift_eval::triple(check, 3),
                ties.unwrap_or_else(|| "–".into()),
                cell(of(&row.predicted_tilt_sigma), 2),
                cell(of(&row.block_tilt_sigma), 2),
                plane.map_or("–".into(), |p| p.count.to_string()),
                cell(plane.map(|p| p.median_m), 3),
                cell(plane.map(|p| p.median_m / a.gsd_m), 2),
                cell(plane.map(|p| p.tilt_mm_per_m), 2),
                cell(
                    plane
                        .zip(of(&row.block_tilt_sigma))
                        .map(|(p, s)| p.tilt_mm_per_m / s),
                    1
                ),
                cell(a.nmad_m, 3),
                row.seconds
            ));
        }
    }
    s
}
