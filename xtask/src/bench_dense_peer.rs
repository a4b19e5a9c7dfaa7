//! The peer of `cargo xtask bench dense`: OpenCV's `StereoSGBM` (Python package, as the other
//! benches run their peers) on the same undistorted images and cameras the dense stage uses —
//! each image rectified with its best source view of the same plan —, triangulated and scored
//! like the dense clouds. Timed with 1 and 2 OpenCV threads.

use std::path::Path;

use anyhow::{Context, bail};
use nalgebra::Vector3;
use timesift::Project;
use timesift::film::ImageSource;
use timesift::stages::{dense_input, dense_view};
use timesift_dense::{EpochInput, EpochPlan, PlanOptions, UndistortMap, plan_epoch};

/// SGBM's clouds per epoch (world coordinates) and its wall times over every image.
pub struct PeerResult {
    pub points: Vec<Vec<Vector3<f64>>>,
    pub seconds_1: f64,
    pub seconds_2: f64,
}

pub fn run_sgbm(project: &Project, level: u32, work: &Path) -> anyhow::Result<PeerResult> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/opencv_sgbm.py");
    let _ = std::fs::remove_dir_all(work);
    std::fs::create_dir_all(work)?;
    let mut result = PeerResult {
        points: Vec::new(),
        seconds_1: 0.0,
        seconds_2: 0.0,
    };
    // Images as the stages see them: a film scan resampled to its camera's frame, masked.
    let source = ImageSource::of(project)?;
    for (e, epoch) in project.epochs.iter().enumerate() {
        let (images, input) = dense_input(project, e)?;
        let plan = plan_epoch(
            &input,
            &PlanOptions {
                level,
                // The peer matches once, at the level itself.
                refine: false,
                ..PlanOptions::default()
            },
        )?;
        let dir = work.join(&epoch.name);
        std::fs::create_dir_all(&dir)?;
        let mut views = Vec::new();
        for (v, vp) in plan.views.iter().enumerate() {
            let png = dir.join(format!("{v}.png"));
            save_working_grey(project, &source, images[v], &input, &plan, v, &png)?;
            let r = vp.cam_from_local.rotation_matrix();
            let t = vp.cam_from_local.translation;
            views.push(serde_json::json!({
                "image": png,
                "width": vp.camera.width,
                "height": vp.camera.height,
                "f": vp.camera.f,
                "cx": vp.camera.cx,
                "cy": vp.camera.cy,
                "R": [[r[(0, 0)], r[(0, 1)], r[(0, 2)]], [r[(1, 0)], r[(1, 1)], r[(1, 2)]], [r[(2, 0)], r[(2, 1)], r[(2, 2)]]],
                "t": [t.x, t.y, t.z],
                "source": vp.sources.first().map(|s| s.view),
                "depth_range": [vp.depth_range.0, vp.depth_range.1],
            }));
        }
        let views_path = dir.join("views.json");
        std::fs::write(
            &views_path,
            serde_json::to_string(&serde_json::json!({ "views": views }))?,
        )?;
        let out = dir.join("points.bin");
        for threads in [1, 2] {
            let output = std::process::Command::new("python3")
                .arg(&script)
                .arg(&views_path)
                .arg(&out)
                .arg(threads.to_string())
                .output()
                .context("running python3 (pip install opencv-python-headless)")?;
            if !output.status.success() {
                bail!(
                    "{}",
                    String::from_utf8_lossy(&output.stderr)
                        .lines()
                        .rfind(|l| !l.trim().is_empty())
                        .unwrap_or("OpenCV SGBM failed")
                );
            }
            let report: serde_json::Value = serde_json::from_slice(&output.stdout)?;
            let seconds = report["seconds"].as_f64().unwrap_or(f64::NAN);
            if threads == 1 {
                result.seconds_1 += seconds;
            } else {
                result.seconds_2 += seconds;
            }
        }
        let bytes = std::fs::read(&out)?;
        let values: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect();
        result.points.push(
            values
                .chunks_exact(3)
                .map(|p| plan.world_from_local(&Vector3::new(p[0], p[1], p[2])))
                .collect(),
        );
    }
    Ok(result)
}

/// View `v` of an epoch's plan as the dense stage matches it (read, masked, undistorted to its
/// working pinhole), saved as an 8-bit grey PNG: the image the peers are fed.
pub(crate) fn save_working_grey(
    project: &Project,
    source: &ImageSource,
    image: usize,
    input: &EpochInput,
    plan: &EpochPlan,
    v: usize,
    png: &Path,
) -> anyhow::Result<()> {
    let vp = &plan.views[v];
    let (decoded, mask) = source.read(project, image, false)?.into_dense_parts();
    let map = UndistortMap::new(&input.views[v].camera, vp.camera, plan.level);
    let working = map.apply(&dense_view(&decoded), mask.as_ref(), true)?;
    let grey: Vec<u8> = working
        .grey
        .data
        .iter()
        .map(|g| (g.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    image::GrayImage::from_raw(vp.camera.width as u32, vp.camera.height as u32, grey)
        .context("image size")?
        .save(png)?;
    Ok(())
}
