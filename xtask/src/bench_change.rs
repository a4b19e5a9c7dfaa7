//! `cargo xtask bench change`: timesift's change detection against its peers on the same real
//! inputs, in one run.
//!
//! - Nuth & Kääb and DoD statistics on consecutive pairs of the sandpyper `mar` DSMs, against xdem
//!   (`pip install xdem`), printed side by side.
//! - M3C2 on clouds made from two of those DSMs (one point per valid cell), against py4dgeo
//!   (`pip install py4dgeo`) with the same parameters and 2 threads: agreement of distances and LoD
//!   where both are defined, how many differ in definedness, and the time ratio.
//!
//! The Python peers run from scripts in `xtask/scripts`; a missing peer is reported and its columns
//! are left empty.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use timesift_change::dod::dem_of_difference;
use timesift_change::grid::Dem;
use timesift_change::m3c2::{M3c2Params, m3c2, subsample_core_points};
use timesift_change::mask::Mask;
use timesift_change::nuth_kaab::{NuthKaabOptions, NuthKaabResult, nuth_kaab};
use timesift_change::stats::statistics;
use timesift_io::geotiff::read_f32;

const XDEM_SCRIPT: &str = include_str!("../scripts/xdem_nk.py");
const PY4DGEO_SCRIPT: &str = include_str!("../scripts/py4dgeo_m3c2.py");

const DATES: [&str; 9] = [
    "20180601", "20180621", "20180727", "20180925", "20181113", "20181211", "20190205", "20190313",
    "20190516",
];
/// sandpyper writes −10000 where there is no data without declaring it.
const SANDPYPER_NODATA: f64 = -10000.0;

fn dsm_path(date: &str) -> PathBuf {
    crate::shared_data()
        .join("sandpyper-mar/dsm")
        .join(format!("mar_{date}_dsm_resampled_1m.tif"))
}

fn load(date: &str) -> anyhow::Result<Dem> {
    let path = dsm_path(date);
    let raster = read_f32(&path).with_context(|| path.display().to_string())?;
    Ok(Dem::from_raster(raster, Some(SANDPYPER_NODATA))?)
}

/// Runs the benchmark. `m3c2_spacing` is the core-point spacing (m).
pub fn run(m3c2_spacing: f64, json: bool) -> anyhow::Result<()> {
    let dir = std::env::temp_dir().join(format!("timesift-bench-change-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let xdem_script = dir.join("xdem_nk.py");
    let py4dgeo_script = dir.join("py4dgeo_m3c2.py");
    std::fs::write(&xdem_script, XDEM_SCRIPT)?;
    std::fs::write(&py4dgeo_script, PY4DGEO_SCRIPT)?;
    let mut report = serde_json::Map::new();
    let nk = nuth_kaab_pairs(&dir, &xdem_script, json)?;
    report.insert("nuth_kaab".into(), nk);
    let m = m3c2_against_py4dgeo(&dir, &py4dgeo_script, m3c2_spacing, json)?;
    report.insert("m3c2".into(), m);
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// The landward side of the `mar` beach (road, dune scrub, grass), west of the vegetation line
/// traced on the 2018-06-01 orthophoto: the beach, surf and sea, which change between surveys, are
/// left out (EPSG:32754).
const STABLE_WKT: &str = "POLYGON ((731598.99 5705559.76, 731578.97 5705509.72, 731553.94 5705459.69, \
    731521.40 5705409.65, 731501.37 5705359.61, 731488.85 5705309.57, 731478.84 5705259.53, \
    731468.83 5705209.49, 731461.32 5705142.44, 731413.76 5705142.44, 731413.76 5705559.76, \
    731598.99 5705559.76))";

/// A translation injected into the later DSM (pixels east, pixels north) so that the fits have a
/// real shift to find; (0, 0) compares them on the data as it is.
const SCENARIOS: [(&str, [f64; 2]); 2] = [
    ("as surveyed", [0.0, 0.0]),
    ("later DSM moved by (+1.5, −2.5) px", [1.5, -2.5]),
];

fn nuth_kaab_pairs(dir: &Path, script: &Path, json: bool) -> anyhow::Result<serde_json::Value> {
    let road = timesift_io::wkt::parse_polygons(STABLE_WKT).map_err(anyhow::Error::msg)?;
    let mut rows = Vec::new();
    for (scenario, injected_px) in SCENARIOS {
        if !json {
            println!(
                "Nuth & Kääb and stable-area DoD statistics (landward polygon), sandpyper `mar` consecutive dates, {scenario}"
            );
            println!(
                "shift = translation applied to the later DSM, pixels (+x east, +y north); DoD = later − earlier on the earlier grid; m"
            );
            println!(
                "timesift: default options (x, y) and xdem-like options (xl: central differences, 72 aspect bins); nmad0/nmad1 = stable NMAD before/after"
            );
            println!(
                "{:<19} | {:>6} {:>8} {:>7} | {:>6} {:>8} {:>7} | {:>7} {:>7} {:>7} | {:>7} {:>7} {:>7} {:>5} | {:>7} {:>7} {:>7} {:>7} {:>5} | {:>6} {:>5}",
                "pair",
                "n",
                "median",
                "nmad",
                "n xdem",
                "median",
                "nmad",
                "x",
                "y",
                "nmad1",
                "x (xl)",
                "y (xl)",
                "nmad1",
                "s",
                "xdem x",
                "xdem y",
                "nmad0",
                "nmad1",
                "s",
                "|Δ| px",
                "agree"
            );
        }
        for pair in DATES.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let reference = load(a)?;
            let original = load(b)?;
            let t = original.grid.transform;
            // Both tools get the later DSM already on the earlier grid (bilinear, nodata propagated),
            // so neither resamples it before its own interpolation: the same input for both.
            let later = original
                .translated(
                    injected_px[0] * t.pixel_width,
                    injected_px[1] * t.pixel_height.abs(),
                    0.0,
                )
                .resample_onto(&reference.grid)?;
            let later_path = dir.join(format!("later_{b}.tif"));
            timesift_io::geotiff::write_f32(&later_path, &later.to_raster())?;
            let stable = Mask::from_polygons(reference.grid, &road);
            let mask_path = dir.join(format!("stable_{a}.tif"));
            let mask_dem = Dem {
                grid: reference.grid,
                values: stable.cells.iter().map(|&c| c as u8 as f32).collect(),
            };
            timesift_io::geotiff::write_f32(&mask_path, &mask_dem.to_raster())?;

            let dod = dem_of_difference(&reference, &later)?;
            let dod_stable = stable.onto(&dod.grid)?;
            let ours_stats = statistics(
                dod.values
                    .iter()
                    .zip(&dod_stable.cells)
                    .filter(|(_, s)| **s)
                    .map(|(&v, _)| v as f64),
            )
            .context("empty stable DoD")?;
            let default = nuth_kaab(
                &reference,
                &later,
                Some(&stable),
                &NuthKaabOptions::default(),
            );
            let t0 = Instant::now();
            let ours = nuth_kaab(
                &reference,
                &later,
                Some(&stable),
                &NuthKaabOptions::xdem_like(),
            );
            let ours_time = t0.elapsed().as_secs_f64();
            let peer = crate::python_json(
                script,
                &[
                    dsm_path(a).display().to_string(),
                    later_path.display().to_string(),
                    "--nodata".into(),
                    SANDPYPER_NODATA.to_string(),
                    "--stable-mask".into(),
                    mask_path.display().to_string(),
                ],
            );
            let rt = reference.grid.transform;
            let in_px = |r: &Result<NuthKaabResult, _>| match r {
                Ok(r) => (
                    r.shift_east_m / rt.pixel_width,
                    r.shift_north_m / rt.pixel_height.abs(),
                    r.nmad_after,
                ),
                Err(_) => (f64::NAN, f64::NAN, f64::NAN),
            };
            let (ox, oy, on1) = in_px(&ours);
            let (dx, dy, dn1) = in_px(&default);
            let get = |path: &[&str]| {
                peer.as_ref()
                    .ok()
                    .and_then(|v| path.iter().try_fold(v, |v, k| v.get(k)))
                    .and_then(|v| v.as_f64())
                    .unwrap_or(f64::NAN)
            };
            let (px, py) = (get(&["shift_x_px"]), get(&["shift_y_px"]));
            let (pn0, pn1) = (get(&["nmad_before"]), get(&["nmad_after"]));
            let xdem_improves = pn1 < pn0;
            let diff = (ox - px).hypot(oy - py);
            let agree = match (xdem_improves, diff <= 0.1) {
                (false, _) => "n/a",
                (true, true) => "yes",
                (true, false) => "NO",
            };
            if !json {
                println!(
                    "{:<19} | {:>6} {:>8.4} {:>7.4} | {:>6} {:>8.4} {:>7.4} | {:>7.3} {:>7.3} {:>7.4} | {:>7.3} {:>7.3} {:>7.4} {:>5.2} | {:>7.3} {:>7.3} {:>7.4} {:>7.4} {:>5.2} | {:>6.3} {:>5}",
                    format!("{a}→{b}"),
                    ours_stats.count,
                    ours_stats.median,
                    ours_stats.nmad,
                    get(&["stats_before", "count"]),
                    get(&["stats_before", "median"]),
                    get(&["stats_before", "nmad"]),
                    dx,
                    dy,
                    dn1,
                    ox,
                    oy,
                    on1,
                    ours_time,
                    px,
                    py,
                    pn0,
                    pn1,
                    get(&["fit_seconds"]),
                    diff,
                    agree
                );
                for r in [&default, &ours] {
                    if let Err(e) = r {
                        println!("    timesift: {e}");
                    }
                }
                if let Err(e) = &peer {
                    println!("    xdem unavailable (pip install xdem): {e}");
                }
            }
            rows.push(serde_json::json!({
                "scenario": scenario,
                "injected_shift_px": injected_px,
                "pair": [a, b],
                "timesift": { "stable_dod": ours_stats, "default": default.as_ref().ok(), "xdem_like": ours.as_ref().ok(), "xdem_like_seconds": ours_time },
                "xdem": peer.as_ref().ok(),
                "shift_difference_px": diff,
                "xdem_improves_nmad": xdem_improves,
            }));
        }
        if !json {
            println!(
                "agree: timesift (xdem-like options) and xdem shifts within 0.1 px, judged where xdem's fit lowers the stable-area NMAD (n/a otherwise)\n"
            );
        }
    }
    Ok(serde_json::Value::Array(rows))
}

fn write_npy(path: &Path, points: &[[f64; 3]]) -> anyhow::Result<()> {
    let mut header = format!(
        "{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, 3), }}",
        points.len()
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    out.write_all(b"\x93NUMPY\x01\x00")?;
    out.write_all(&(header.len() as u16).to_le_bytes())?;
    out.write_all(header.as_bytes())?;
    for p in points {
        for c in p {
            out.write_all(&c.to_le_bytes())?;
        }
    }
    out.flush()?;
    Ok(())
}

fn m3c2_against_py4dgeo(
    dir: &Path,
    script: &Path,
    spacing: f64,
    json: bool,
) -> anyhow::Result<serde_json::Value> {
    let (a, b) = ("20180601", "20180621");
    let e1 = load(a)?.to_points();
    let e2 = load(b)?.to_points();
    let core = subsample_core_points(&e1, spacing)?;
    let params = M3c2Params {
        normal_radii: vec![2.5],
        // max_depth / cylinder_radius odd: py4dgeo's slab search drops points exactly on a slab
        // boundary, and with an even number of slabs the core point's own plane is one.
        cylinder_radius: 1.5,
        max_depth: 4.5,
        registration_error: 0.05,
        ..M3c2Params::default()
    };
    // Best of 3, trees included (as in py4dgeo's timed run).
    let mut best = f64::INFINITY;
    let mut ours = Vec::new();
    for _ in 0..3 {
        let t0 = Instant::now();
        ours = m3c2(&e1, &e2, &core, &params)?;
        best = best.min(t0.elapsed().as_secs_f64());
    }
    for (name, pts) in [("e1.npy", &e1), ("e2.npy", &e2), ("core.npy", &core)] {
        write_npy(&dir.join(name), pts)?;
    }
    let out_bin = dir.join("py4dgeo.bin");
    let peer = crate::python_json(
        script,
        &[
            dir.join("e1.npy").display().to_string(),
            dir.join("e2.npy").display().to_string(),
            dir.join("core.npy").display().to_string(),
            out_bin.display().to_string(),
            "--normal-radius".into(),
            params.normal_radii[0].to_string(),
            "--cyl-radius".into(),
            params.cylinder_radius.to_string(),
            "--max-distance".into(),
            params.max_depth.to_string(),
            "--registration-error".into(),
            params.registration_error.to_string(),
            "--threads".into(),
            "2".into(),
            "--include-tree-build".into(),
        ],
    );
    let threads = rayon::current_num_threads();
    let mut summary = serde_json::json!({
        "pair": [a, b],
        "points": [e1.len(), e2.len()],
        "core_points": core.len(),
        "core_spacing_m": spacing,
        "normal_radius": params.normal_radii[0],
        "cylinder_radius": params.cylinder_radius,
        "max_depth": params.max_depth,
        "registration_error": params.registration_error,
        "timesift_seconds": best,
        "timesift_threads": threads,
    });
    let peer = match peer {
        Ok(v) => v,
        Err(e) => {
            if !json {
                println!(
                    "M3C2: timesift {best:.3} s on {} core points; py4dgeo unavailable (pip install py4dgeo): {e}",
                    core.len()
                );
            }
            summary["py4dgeo"] = serde_json::Value::Null;
            return Ok(summary);
        }
    };
    let bytes = std::fs::read(&out_bin)?;
    if bytes.len() != core.len() * 16 {
        bail!(
            "py4dgeo wrote {} bytes for {} core points",
            bytes.len(),
            core.len()
        );
    }
    let value = |i: usize| f64::from_le_bytes(bytes[i * 8..i * 8 + 8].try_into().unwrap_or([0; 8]));
    let (mut both, mut close, mut lod_close, mut only_ours, mut only_peer, mut worst) =
        (0usize, 0usize, 0usize, 0usize, 0usize, 0.0f64);
    let mut lod_both = 0usize;
    for (i, p) in ours.iter().enumerate() {
        let (d, lod) = (value(2 * i), value(2 * i + 1));
        match (p.distance.is_finite(), d.is_finite()) {
            (true, true) => {
                both += 1;
                let diff = (p.distance - d).abs();
                worst = worst.max(diff);
                close += (diff <= 1e-3) as usize;
                if p.lod95.is_finite() && lod.is_finite() {
                    lod_both += 1;
                    lod_close += ((p.lod95 - lod).abs() <= 0.01 * lod.abs()) as usize;
                }
            }
            (true, false) => only_ours += 1,
            (false, true) => only_peer += 1,
            (false, false) => {}
        }
    }
    let peer_time = peer["seconds"].as_f64().unwrap_or(f64::NAN);
    let fraction = close as f64 / both.max(1) as f64;
    let lod_fraction = lod_close as f64 / lod_both.max(1) as f64;
    if !json {
        println!(
            "M3C2, sandpyper {a} → {b}: {} + {} points, {} core points ({spacing} m voxels), normal radius {} m, cylinder radius {} m, max depth ±{} m, registration error {} m",
            e1.len(),
            e2.len(),
            core.len(),
            params.normal_radii[0],
            params.cylinder_radius,
            params.max_depth,
            params.registration_error
        );
        println!("py4dgeo {}", peer["version"].as_str().unwrap_or("?"));
        println!("defined in both: {both}; only timesift: {only_ours}; only py4dgeo: {only_peer}");
        println!(
            "distances within 1 mm: {close} of {both} ({:.3} %), largest difference {:.3e} m",
            100.0 * fraction,
            worst
        );
        println!(
            "LoD95 within 1 %: {lod_close} of {lod_both} ({:.3} %)",
            100.0 * lod_fraction
        );
        println!(
            "time (trees + normals + distances): timesift {:.4} s ({threads} threads), py4dgeo {:.4} s ({} threads), ratio py4dgeo/timesift {:.2}",
            best,
            peer_time,
            peer["threads"],
            peer_time / best
        );
    }
    summary["py4dgeo"] = peer;
    summary["defined_in_both"] = both.into();
    summary["only_timesift"] = only_ours.into();
    summary["only_py4dgeo"] = only_peer.into();
    summary["distance_within_1mm_fraction"] = fraction.into();
    summary["largest_distance_difference_m"] = worst.into();
    summary["lod_within_1pct_fraction"] = lod_fraction.into();
    summary["time_ratio_py4dgeo_over_timesift"] = (peer_time / best).into();
    Ok(summary)
}
