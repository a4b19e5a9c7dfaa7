//! Every path of a project directory that timesift reads or writes, in one place (the project
//! directory of docs/design.md): the inputs' defaults live in the root's `config`, everything under `work/` (resumable intermediate results) and
//! `out/` (the products of docs/design.md) is named here and nowhere else.

use std::path::{Path, PathBuf};

/// The paths of one project directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Layout {
    dir: PathBuf,
}

impl Layout {
    /// The layout of the project in `dir`.
    pub fn new(dir: &Path) -> Layout {
        Layout {
            dir: dir.to_path_buf(),
        }
    }

    /// The project directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `project.toml`.
    pub fn project_toml(&self) -> PathBuf {
        self.dir.join("project.toml")
    }

    /// `truth/` of a synthetic project.
    pub fn truth_dir(&self) -> PathBuf {
        self.dir.join("truth")
    }

    /// `truth/cameras.json` of a synthetic project.
    pub fn truth_cameras(&self) -> PathBuf {
        self.truth_dir().join("cameras.json")
    }

    // ---- work/: intermediate results, resumable --------------------------------------------

    /// `work/`.
    pub fn work_dir(&self) -> PathBuf {
        self.dir.join("work")
    }

    /// `work/features/`: one feature file per image.
    pub fn features_dir(&self) -> PathBuf {
        self.work_dir().join("features")
    }

    /// `work/features/<n>.feat` of image number `image` (its index in the project).
    pub fn feature_file(&self, image: usize) -> PathBuf {
        self.features_dir().join(format!("{image}.feat"))
    }

    /// `work/matches/`: one match file per matched pair.
    pub fn matches_dir(&self) -> PathBuf {
        self.work_dir().join("matches")
    }

    /// `work/matches/<a>_<b>.match`.
    pub fn match_file(&self, a: usize, b: usize) -> PathBuf {
        self.matches_dir().join(format!("{a}_{b}.match"))
    }

    /// The image pair of a `work/matches/<a>_<b>.match` file; `None` for any other file.
    pub fn match_file_pair(path: &Path) -> Option<(usize, usize)> {
        let stem = path.file_name()?.to_str()?.strip_suffix(".match")?;
        let (a, b) = stem.split_once('_')?;
        Some((a.parse().ok()?, b.parse().ok()?))
    }

    /// `work/matches/summary.json`.
    pub fn match_summary(&self) -> PathBuf {
        self.matches_dir().join("summary.json")
    }

    /// `work/dense/<epoch>/`: the dense stage's depth maps of one epoch.
    pub fn dense_work_dir(&self, epoch: &str) -> PathBuf {
        self.work_dir().join("dense").join(epoch)
    }

    /// `work/dense/<epoch>/pass<k>/<n>.exr`: depth, normal and cost of image number `image`
    /// after pass `pass`.
    pub fn depth_map_file(&self, epoch: &str, pass: usize, image: usize) -> PathBuf {
        self.dense_work_dir(epoch)
            .join(format!("pass{pass}"))
            .join(format!("{image}.exr"))
    }

    /// `work/dense/<epoch>/filtered/<n>.exr`: the filtered depth map of image number `image`.
    pub fn filtered_map_file(&self, epoch: &str, image: usize) -> PathBuf {
        self.dense_work_dir(epoch)
            .join("filtered")
            .join(format!("{image}.exr"))
    }

    /// `work/raster/<epoch>.dem.json` and `.ortho.json`: what an epoch's DEM or ortho was made
    /// from, so a resumed run redoes only what changed.
    pub fn raster_settings(&self, epoch: &str, product: &str) -> PathBuf {
        self.work_dir()
            .join("raster")
            .join(format!("{epoch}.{product}.json"))
    }

    /// `work/align.json`: what the orientation was made from.
    pub fn align_settings(&self) -> PathBuf {
        self.work_dir().join("align.json")
    }

    /// `work/fiducials.json`: what the interior orientations of the scans were made from.
    pub fn fiducials_settings(&self) -> PathBuf {
        self.work_dir().join("fiducials.json")
    }

    /// `work/change/<a>__<b>.json`: what a pair's change products were made from.
    pub fn change_settings(&self, a: &str, b: &str) -> PathBuf {
        self.work_dir()
            .join("change")
            .join(format!("{a}__{b}.json"))
    }

    /// `work/run.json`: the wall time and summary of each stage's latest run (the report's
    /// time table).
    pub fn run_log(&self) -> PathBuf {
        self.work_dir().join("run.json")
    }

    /// `work/matches/pairs.json`: the pairs the match stage's units match, chosen once by its
    /// first step so that every unit splits the same list.
    pub fn match_pairs(&self) -> PathBuf {
        self.matches_dir().join("pairs.json")
    }

    /// `work/dense/<epoch>/summary.json`: what the epoch's fusion made (points, times), read by
    /// the step that writes `out/dense.json`.
    pub fn dense_summary(&self, epoch: &str) -> PathBuf {
        self.dense_work_dir(epoch).join("summary.json")
    }

    /// `work/tasks/<step>/`: the completion records of one step's units.
    pub fn task_records_dir(&self, step: &str) -> PathBuf {
        self.work_dir().join("tasks").join(step)
    }

    /// `work/tasks/<step>/<i>-of-<n>.json`: unit `i` (1-based) of `n` of a step is complete.
    pub fn task_record(&self, step: &str, index: usize, count: usize) -> PathBuf {
        self.task_records_dir(step)
            .join(format!("{index}-of-{count}.json"))
    }

    /// `work/slurm/`: the batch scripts, job ids and task logs of `--executor slurm`.
    pub fn slurm_dir(&self) -> PathBuf {
        self.work_dir().join("slurm")
    }

    /// `work/lock`: held (an OS file lock) by the process running or submitting the project.
    pub fn lock_file(&self) -> PathBuf {
        self.work_dir().join("lock")
    }

    /// The file in which a folder of `work/` records the settings its results were made with.
    pub fn settings_file(dir: &Path) -> PathBuf {
        dir.join("settings.json")
    }

    // ---- out/: the products of docs/design.md ----------------------------------------------------

    /// `out/`.
    pub fn out_dir(&self) -> PathBuf {
        self.dir.join("out")
    }

    /// `out/cameras.json`.
    pub fn cameras_json(&self) -> PathBuf {
        self.out_dir().join("cameras.json")
    }

    /// `out/colmap/`.
    pub fn colmap_dir(&self) -> PathBuf {
        self.out_dir().join("colmap")
    }

    /// `out/tiepoints.ply`.
    pub fn tiepoints_ply(&self) -> PathBuf {
        self.out_dir().join("tiepoints.ply")
    }

    /// `out/report.json`.
    pub fn report_json(&self) -> PathBuf {
        self.out_dir().join("report.json")
    }

    /// `out/stable_found.tif`: the ground the align stage found unchanged, where no stable
    /// areas were given.
    pub fn stable_found(&self) -> PathBuf {
        self.out_dir().join("stable_found.tif")
    }

    /// `out/fiducials.json`: every scan's marks and interior orientation.
    pub fn fiducials_json(&self) -> PathBuf {
        self.out_dir().join("fiducials.json")
    }

    /// `out/fiducials.csv`: every measured mark (docs/design.md: `image,mark,u,v,residual_px`).
    pub fn fiducials_csv(&self) -> PathBuf {
        self.out_dir().join("fiducials.csv")
    }

    /// `out/fiducials.png`: the contact sheet of every mark with its measured centre.
    pub fn fiducials_sheet(&self) -> PathBuf {
        self.out_dir().join("fiducials.png")
    }

    /// `out/fiducials_frame_<camera>.png`: a scan of a film camera resampled to its frame, to
    /// draw a `[[camera]] mask` on.
    pub fn fiducials_frame(&self, camera: &str) -> PathBuf {
        self.out_dir().join(format!("fiducials_frame_{camera}.png"))
    }

    /// `out/report.html`.
    pub fn report_html(&self) -> PathBuf {
        self.out_dir().join("report.html")
    }

    /// `out/dense.json`: what the dense stage did per epoch.
    pub fn dense_report(&self) -> PathBuf {
        self.out_dir().join("dense.json")
    }

    /// `out/grid.json`: the one raster lattice of the project.
    pub fn grid_json(&self) -> PathBuf {
        self.out_dir().join("grid.json")
    }

    /// `out/raster.json`: what the dem and ortho stages did per epoch.
    pub fn raster_report(&self) -> PathBuf {
        self.out_dir().join("raster.json")
    }

    /// `out/epochs/<epoch>/`.
    pub fn epoch_dir(&self, epoch: &str) -> PathBuf {
        self.out_dir().join("epochs").join(epoch)
    }

    /// `out/epochs/<epoch>/dense.laz`.
    pub fn dense_cloud(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("dense.laz")
    }

    /// `out/epochs/<epoch>/dem.tif`.
    pub fn dem(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("dem.tif")
    }

    /// `out/epochs/<epoch>/dem_count.tif`: points per DEM cell.
    pub fn dem_count(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("dem_count.tif")
    }

    /// `out/epochs/<epoch>/dem_std.tif`: standard deviation of the heights in each DEM cell.
    pub fn dem_std(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("dem_std.tif")
    }

    /// `out/epochs/<epoch>/dem_filled.tif`: 1 where a DEM height was interpolated over a gap.
    pub fn dem_filled(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("dem_filled.tif")
    }

    /// `out/epochs/<epoch>/dem.png`: hillshade preview.
    pub fn dem_preview(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("dem.png")
    }

    /// `out/epochs/<epoch>/ortho.tif`.
    pub fn ortho(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("ortho.tif")
    }

    /// `out/epochs/<epoch>/ortho.png`: downscaled preview.
    pub fn ortho_preview(&self, epoch: &str) -> PathBuf {
        self.epoch_dir(epoch).join("ortho.png")
    }

    /// `out/change/<a>__<b>/stats.json`: the DEM comparison's `DemReport` (the root's `compare`).
    pub fn change_stats(&self, a: &str, b: &str) -> PathBuf {
        self.change_dir(a, b).join("stats.json")
    }

    /// `out/change/<a>__<b>/m3c2_stats.json`: the cloud comparison's
    /// `CloudReport` (the root's `compare`).
    pub fn m3c2_stats(&self, a: &str, b: &str) -> PathBuf {
        self.change_dir(a, b).join("m3c2_stats.json")
    }

    /// `out/export/<format>/`: what `timesift export` writes by default.
    pub fn export_dir(&self, format: &str) -> PathBuf {
        self.out_dir().join("export").join(format)
    }

    /// `out/change/<a>__<b>/`.
    pub fn change_dir(&self, a: &str, b: &str) -> PathBuf {
        self.out_dir().join("change").join(format!("{a}__{b}"))
    }

    /// Every output file docs/design.md names for a project of these epochs (present or not), in a
    /// fixed order: what `timesift info` lists.
    pub fn outputs(&self, epochs: &[&str]) -> Vec<PathBuf> {
        let mut files = vec![
            self.cameras_json(),
            self.colmap_dir().join("cameras.txt"),
            self.colmap_dir().join("images.txt"),
            self.colmap_dir().join("points3D.txt"),
            self.tiepoints_ply(),
            self.report_json(),
            self.report_html(),
            self.stable_found(),
            self.grid_json(),
        ];
        for e in epochs {
            files.extend([self.dense_cloud(e), self.dem(e), self.ortho(e)]);
        }
        for a in epochs {
            for b in epochs.iter().filter(|b| *b != a) {
                let dir = self.change_dir(a, b);
                files.extend(["dod.tif", "m3c2.laz", "stats.json"].map(|f| dir.join(f)));
            }
        }
        files
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn match_files_name_their_pair() {
        let layout = Layout::new(Path::new("/p"));
        let f = layout.match_file(3, 17);
        assert_eq!(Layout::match_file_pair(&f), Some((3, 17)));
        assert_eq!(Layout::match_file_pair(&layout.match_summary()), None);
        assert_eq!(
            layout.dense_cloud("2019"),
            PathBuf::from("/p/out/epochs/2019/dense.laz")
        );
    }
}
