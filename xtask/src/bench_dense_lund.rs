//! The real-data part of `cargo xtask bench dense`: `lund` (29 street photos) oriented by the
//! align stage, then the dense stage; how many fused points reproject within 1 pixel into each
//! of their (at least 3) images, and a PNG of the cloud seen from the first camera beside the
//! photo, for a person to look at.

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use timesift::Project;
use timesift::stages::Stage;
use timesift_core::{CameraModel, project_world};
use timesift_io::pointcloud::{AttributeValues, read_las};

pub fn run(out: &Path, level: u32) -> anyhow::Result<String> {
    let images = crate::lund_images()?;
    let dir = out.join("lund");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("images"))?;
    let source = images
        .first()
        .and_then(|p| p.parent())
        .context("no lund image")?;
    std::os::unix::fs::symlink(std::fs::canonicalize(source)?, dir.join("images/lund"))?;
    std::fs::write(
        dir.join("project.toml"),
        format!(
            "crs = \"EPSG:32633\"\n[[epoch]]\nname = \"lund\"\nimages = \"images/lund/*.jpg\"\n[dense]\nlevel = {level}\n"
        ),
    )?;
    let project = Project::load(&dir)?;
    let start = Instant::now();
    timesift::stages::run(&project, Some(Stage::Features), Some(Stage::Align))?;
    let align_seconds = start.elapsed().as_secs_f64();
    let start = Instant::now();
    timesift::stages::run(&project, Some(Stage::Dense), Some(Stage::Dense))?;
    let dense_seconds = start.elapsed().as_secs_f64();
    let cloud = read_las(&project.layout().dense_cloud("lund"))?;
    let attribute = |name: &str| cloud.attributes.iter().find(|a| a.name == name);
    let images_of: Vec<u8> = match attribute("images").map(|a| &a.values) {
        Some(AttributeValues::U8(v)) => v.clone(),
        _ => anyhow::bail!("dense.laz without the images attribute"),
    };
    let reprojection: Vec<f32> = match attribute("reprojection_px").map(|a| &a.values) {
        Some(AttributeValues::F32(v)) => v.clone(),
        _ => anyhow::bail!("dense.laz without the reprojection_px attribute"),
    };
    let n = cloud.positions.len();
    let good = images_of
        .iter()
        .zip(&reprojection)
        .filter(|(i, r)| **i >= 3 && **r <= 1.0)
        .count();
    let mut sorted = reprojection.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted.get(n / 2).copied().unwrap_or(f32::NAN);
    // The cloud from the first oriented camera, beside the photo.
    let cameras = timesift_io::cameras_json::read_cameras_json(&project.layout().cameras_json())?;
    let first = cameras
        .images
        .iter()
        .find(|im| im.pose.is_some())
        .context("no oriented image")?;
    let camera = &cameras.cameras[&first.camera];
    let pose = first.pose.unwrap_or_default();
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let scale = (1200.0 / w as f64).min(1.0);
    let (rw, rh) = ((w as f64 * scale) as usize, (h as f64 * scale) as usize);
    let mut depth = vec![f64::INFINITY; rw * rh];
    let mut canvas = image::RgbImage::new(2 * rw as u32, rh as u32);
    let colors = cloud.colors.clone().unwrap_or_default();
    for (k, p) in cloud.positions.iter().enumerate() {
        let x = nalgebra::Vector3::new(p[0], p[1], p[2]);
        let z = pose.transform_point(&x).z;
        let Ok(px) = project_world(camera, &pose, &x) else {
            continue;
        };
        let (u, v) = (px.x * scale, px.y * scale);
        for (du, dv) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
            let (i, j) = ((u + du) as i64, (v + dv) as i64);
            if i < 0 || j < 0 || i >= rw as i64 || j >= rh as i64 {
                continue;
            }
            let c = j as usize * rw + i as usize;
            if z < depth[c] {
                depth[c] = z;
                let rgb = colors.get(k).copied().unwrap_or([0; 3]);
                canvas.put_pixel(i as u32, j as u32, image::Rgb(rgb.map(|v| (v >> 8) as u8)));
            }
        }
    }
    let photo = image::open(project.dir.join(&first.name))?
        .resize_exact(rw as u32, rh as u32, image::imageops::FilterType::Triangle)
        .to_rgb8();
    image::imageops::overlay(&mut canvas, &photo, rw as i64, 0);
    let png = out.join("lund_dense.png");
    canvas.save(&png)?;
    Ok(format!(
        "\n## lund (real, {} images, align stage's cameras, level {level})\n\n\
         oriented in {align_seconds:.1} s; dense stage {dense_seconds:.1} s; {n} fused points; \
         {good} ({:.1} %) from at least 3 images that all reproject within 1 px \
         (pixels of the working images); median worst reprojection {median:.3} px.\n\
         Rendering from the first camera beside its photo: {}\n",
        images.len(),
        100.0 * good as f64 / n.max(1) as f64,
        png.display()
    ))
}
