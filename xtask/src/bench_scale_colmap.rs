//! The scale bench's peers: COLMAP 4's incremental and global mappers (pycolmap, `pip install
//! pycolmap`) on timesift's own verified matches of the same block, scored like timesift's
//! orientation by `xtask/scripts/colmap_scale.py` (similarity to the GNSS priors, and to the
//! GCPs; check points intersected per epoch from their markers).

use std::io::Write;
use std::path::Path;
use std::process::Command;

use anyhow::Context;
use timesift::Project;
use timesift_io::layout::Layout;

/// One mapper's orientation of the block, scored.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct PeerRow {
    pub mapper: String,
    /// Wall seconds (none for timesift's own block: the align stage's time is in the table).
    pub seconds: Option<f64>,
    pub registered: Option<usize>,
    /// Check-point RMSE (dE, dN, dH), m, after a similarity to the GNSS priors.
    pub check_rmse_gnss_m: Option<[f64; 3]>,
    /// The same after a similarity to the GCPs intersected from their markers.
    pub check_rmse_gcps_m: Option<[f64; 3]>,
    pub error: Option<String>,
}

/// Least verified matches for a pair to be handed to COLMAP (its own `min_num_matches`).
const MIN_MATCHES: usize = 15;

/// Blocks larger than this run COLMAP's global mapper only: its incremental mapper re-adjusts
/// the growing block and would take most of a bench run's time on 2 cores, and the issue's
/// anchor at these sizes is the global mapper.
pub const COLMAP_INCREMENTAL_UP_TO: usize = 400;

/// Writes the block's keypoints and verified matches for COLMAP, runs its mappers with
/// `threads` threads (the incremental one only up to [`COLMAP_INCREMENTAL_UP_TO`] images), and
/// returns their rows and timesift's own, scored alike.
pub fn run_peers(dir: &Path, python: &Path, threads: usize) -> anyhow::Result<Vec<PeerRow>> {
    let project = Project::load(dir)?;
    let layout = project.layout();
    let input = dir.join("work/colmap-peer");
    let _ = std::fs::remove_dir_all(&input);
    std::fs::create_dir_all(input.join("kp"))?;
    export_block(&project, &layout, &input)?;
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/colmap_scale.py");
    let out_json = input.join("rows.json");
    let mut command = Command::new(python);
    command
        .arg(&script)
        .arg(&input)
        .arg(dir)
        .arg(&out_json)
        .arg("--threads")
        .arg(threads.to_string());
    if project.images.len() > COLMAP_INCREMENTAL_UP_TO {
        command.arg("--skip-incremental");
    }
    let status = command
        .env("OMP_NUM_THREADS", threads.to_string())
        .status()
        .with_context(|| format!("{} {}", python.display(), script.display()))?;
    anyhow::ensure!(status.success(), "{} failed: {status}", script.display());
    let text = std::fs::read_to_string(&out_json)?;
    let rows: Vec<PeerRow> =
        serde_json::from_str(&text).with_context(|| out_json.display().to_string())?;
    // The first row times the database's writing, not a mapper.
    Ok(rows
        .into_iter()
        .filter(|r| r.mapper != "database")
        .collect())
}

/// `images.csv`, `kp/<i>.f32` and `matches.bin` (see the script's doc).
fn export_block(project: &Project, layout: &Layout, input: &Path) -> anyhow::Result<()> {
    let mut images = String::from("id,name,epoch,width,height,focal_px\n");
    for (i, image) in project.images.iter().enumerate() {
        let path = project.dir.join(&image.name);
        let (w, h) = image::image_dimensions(&path).with_context(|| path.display().to_string())?;
        let f = timesift_io::exif::read_exif(&path)
            .ok()
            .and_then(|e| e.focal_length_px(w, h))
            .unwrap_or(1.2 * w.max(h) as f64);
        images.push_str(&format!(
            "{i},{},{},{w},{h},{f}\n",
            image.name,
            project.epochs[image.epoch.index()].name
        ));
        let (keypoints, _) = timesift_matching::storage::read_features(&layout.feature_file(i))?;
        let bytes: Vec<u8> = keypoints
            .iter()
            .flat_map(|k| [k.x as f32, k.y as f32])
            .flat_map(f32::to_le_bytes)
            .collect();
        std::fs::write(input.join(format!("kp/{i}.f32")), bytes)?;
    }
    std::fs::write(input.join("images.csv"), images)?;
    let mut out = std::io::BufWriter::new(std::fs::File::create(input.join("matches.bin"))?);
    let mut files: Vec<_> = std::fs::read_dir(layout.matches_dir())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter_map(|p| Layout::match_file_pair(&p).map(|pair| (pair, p)))
        .collect();
    files.sort();
    for ((a, b), path) in files {
        let matches = timesift_matching::storage::read_matches(&path)?;
        if matches.len() < MIN_MATCHES {
            continue;
        }
        for v in [a as u32, b as u32, matches.len() as u32] {
            out.write_all(&v.to_le_bytes())?;
        }
        for m in &matches {
            out.write_all(&m.query.to_le_bytes())?;
            out.write_all(&m.train.to_le_bytes())?;
        }
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::PeerRow;

    #[test]
    fn the_script_s_rows_read_as_peer_rows() {
        // As colmap_scale.py writes them: the database row, a block without seconds, a failure.
        let text = r#"[
 {"mapper": "database", "seconds": 1.5, "images": 200, "pairs": 4206},
 {"mapper": "timesift", "seconds": null, "registered": 200,
  "check_rmse_gnss_m": [0.5, 0.8, 0.57], "checks_gnss": 40,
  "check_rmse_gcps_m": [0.04, 0.03, 0.09], "checks_gcps": 40},
 {"mapper": "colmap-global", "seconds": 12.0, "error": "no model"}
]"#;
        let rows: Vec<PeerRow> = serde_json::from_str(text).unwrap();
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[1].seconds, None);
        assert_eq!(rows[1].registered, Some(200));
        assert_eq!(rows[1].check_rmse_gcps_m, Some([0.04, 0.03, 0.09]));
        assert_eq!(rows[2].error.as_deref(), Some("no model"));
        assert_eq!(rows[2].check_rmse_gnss_m, None);
    }
}
