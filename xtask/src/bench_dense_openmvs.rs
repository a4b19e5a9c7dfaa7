//! The multi-view peer of `cargo xtask bench dense`: OpenMVS's `DensifyPointCloud` (CPU build;
//! `xtask/scripts/build_openmvs.sh` builds it), fed the images and cameras the dense stage
//! works from: each view undistorted to its ideal pinhole at full resolution (a COLMAP
//! `PINHOLE` camera), its pose in the plan's local frame, and the sparse points with their
//! tracks, written as a COLMAP text model that OpenMVS's `InterfaceCOLMAP` reads. It then
//! matches at `--resolution-level` log2(level), so that its depth maps are as large as the
//! dense stage's, with its own defaults otherwise (5 views, 3 iterations, geometric pass).
//! Timed like the dense stage (a process of its own, CPU seconds, peak memory), scored the
//! same way.

use std::fmt::Write as _;
use std::io::{BufRead, Read};
use std::path::Path;
use std::process::Command;

use anyhow::{Context, bail};
use nalgebra::Vector3;
use timesift::Project;
use timesift::film::ImageSource;
use timesift::stages::dense_input;
use timesift_dense::{PlanOptions, plan_epoch};

use crate::bench_dense_peer::save_working_grey;

use crate::bench_dense_time::{DenseRun, time_command};

/// OpenMVS's clouds per epoch (world coordinates) and its cost, summed over the epochs.
pub struct OpenMvsResult {
    pub points: Vec<Vec<Vector3<f64>>>,
    pub run: DenseRun,
}

/// Runs OpenMVS (`bin` holds `InterfaceCOLMAP` and `DensifyPointCloud`) on every epoch of
/// `project` with `threads` threads, in `work`.
pub fn run_openmvs(
    project: &Project,
    level: u32,
    bin: &Path,
    work: &Path,
    threads: usize,
) -> anyhow::Result<OpenMvsResult> {
    for exe in ["InterfaceCOLMAP", "DensifyPointCloud"] {
        if !bin.join(exe).is_file() {
            bail!(
                "{}: no {exe} (build it with xtask/scripts/build_openmvs.sh)",
                bin.display()
            );
        }
    }
    let _ = std::fs::remove_dir_all(work);
    std::fs::create_dir_all(work)?;
    let work = work.canonicalize()?;
    let source = ImageSource::of(project)?;
    let mut result = OpenMvsResult {
        points: Vec::new(),
        run: DenseRun {
            threads,
            ..DenseRun::default()
        },
    };
    for (e, epoch) in project.epochs.iter().enumerate() {
        let (images, input) = dense_input(project, e)?;
        let plan = plan_epoch(
            &input,
            &PlanOptions {
                level: 1,
                refine: false,
                ..PlanOptions::default()
            },
        )?;
        let dir = work.join(&epoch.name);
        let image_dir = dir.join("images");
        std::fs::create_dir_all(&image_dir)?;
        std::fs::create_dir_all(dir.join("sparse"))?;
        // cameras.txt and the images, one PINHOLE camera per view.
        let mut cameras = String::new();
        for (v, vp) in plan.views.iter().enumerate() {
            let png = image_dir.join(format!("{v}.png"));
            save_working_grey(project, &source, images[v], &input, &plan, v, &png)?;
            // COLMAP's pixel convention is the project's: the top-left pixel's centre at (0.5, 0.5).
            writeln!(
                cameras,
                "{} PINHOLE {} {} {} {} {} {}",
                v + 1,
                vp.camera.width,
                vp.camera.height,
                vp.camera.f,
                vp.camera.f,
                vp.camera.cx,
                vp.camera.cy
            )?;
        }
        // Each sparse point's observations, projected with the working cameras.
        let mut observations: Vec<Vec<(f64, f64, usize)>> = vec![Vec::new(); plan.views.len()];
        let mut points = String::new();
        for (p, point) in input.points.iter().enumerate() {
            let local = plan.local_from_world(&point.position);
            let mut track = String::new();
            for &v in &point.views {
                let Some(vp) = plan.views.get(v) else {
                    continue;
                };
                let Some(px) = vp
                    .camera
                    .project(&vp.cam_from_local.transform_point(&local))
                else {
                    continue;
                };
                write!(track, " {} {}", v + 1, observations[v].len())?;
                observations[v].push((px.x, px.y, p + 1));
            }
            if !track.is_empty() {
                writeln!(
                    points,
                    "{} {} {} {} 128 128 128 0{track}",
                    p + 1,
                    local.x,
                    local.y,
                    local.z
                )?;
            }
        }
        let mut images_txt = String::new();
        for (v, vp) in plan.views.iter().enumerate() {
            let q = vp.cam_from_local.rotation.quaternion();
            let t = vp.cam_from_local.translation;
            writeln!(
                images_txt,
                "{} {} {} {} {} {} {} {} {} {v}.png",
                v + 1,
                q.w,
                q.i,
                q.j,
                q.k,
                t.x,
                t.y,
                t.z,
                v + 1
            )?;
            let line: Vec<String> = observations[v]
                .iter()
                .map(|(x, y, id)| format!("{x} {y} {id}"))
                .collect();
            writeln!(images_txt, "{}", line.join(" "))?;
        }
        std::fs::write(dir.join("sparse/cameras.txt"), cameras)?;
        std::fs::write(dir.join("sparse/images.txt"), images_txt)?;
        std::fs::write(dir.join("sparse/points3D.txt"), points)?;
        let status = Command::new(bin.join("InterfaceCOLMAP"))
            .arg("-i")
            .arg(&dir)
            .arg("-o")
            .arg(dir.join("scene.mvs"))
            .arg("--image-folder")
            .arg(&image_dir)
            .args(["-v", "0"])
            .current_dir(&dir)
            .output()
            .context("running InterfaceCOLMAP")?;
        if !status.status.success() {
            bail!(
                "InterfaceCOLMAP failed on {}: {}",
                dir.display(),
                String::from_utf8_lossy(&status.stderr)
            );
        }
        let resolution_level = level.max(1).trailing_zeros();
        let mut densify = Command::new(bin.join("DensifyPointCloud"));
        densify
            .arg("-w")
            .arg(&dir)
            .args(["-i", "scene.mvs", "-o", "dense.mvs", "-v", "0"])
            .args(["--resolution-level", &resolution_level.to_string()])
            // Its default floor (640 px) would keep small images at full resolution.
            .args(["--min-resolution", "64"])
            .args(["--max-threads", &threads.to_string()])
            .args(["--tower-mode", "0"])
            .current_dir(&dir)
            .stdout(std::process::Stdio::null());
        let run = time_command(&mut densify, threads)?;
        result.run.wall += run.wall;
        result.run.cpu += run.cpu;
        result.run.peak_mib = result.run.peak_mib.max(run.peak_mib);
        let cloud = read_ply_positions(&dir.join("dense.ply"))?;
        result.points.push(
            cloud
                .iter()
                .map(|p| plan.world_from_local(&p.cast::<f64>()))
                .collect(),
        );
    }
    Ok(result)
}

/// One vertex property of a PLY header.
enum Property {
    /// A scalar of this many bytes; `Some(k)` for x, y or z (k = 0, 1, 2).
    Scalar(usize, Option<usize>),
    /// A list: the byte size of its count and of each item.
    List(usize, usize),
}

fn ply_type_size(kind: &str) -> Option<usize> {
    Some(match kind {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// The vertex positions of a binary little-endian PLY whose first element is its vertices
/// (OpenMVS's dense cloud: float x, y, z, colour, normal and the lists of views that see it).
pub fn read_ply_positions(path: &Path) -> anyhow::Result<Vec<Vector3<f32>>> {
    let bad = |what: String| anyhow::anyhow!("{}: {what}", path.display());
    let file = std::fs::File::open(path).with_context(|| path.display().to_string())?;
    let mut reader = std::io::BufReader::new(file);
    let mut vertices = None;
    let mut in_vertex = false;
    let mut properties = Vec::new();
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line)? == 0 {
            return Err(bad("the PLY header has no end_header".into()));
        }
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", format, _] if *format != "binary_little_endian" => {
                return Err(bad(format!(
                    "PLY format {format}, expected binary_little_endian"
                )));
            }
            ["element", name, count] => {
                in_vertex = *name == "vertex";
                if in_vertex {
                    if !properties.is_empty() || vertices.is_some() {
                        return Err(bad("the vertices are not the first element".into()));
                    }
                    vertices = Some(count.parse::<usize>()?);
                }
            }
            ["property", "list", count, item, _] if in_vertex => {
                let size = |k: &str| ply_type_size(k).ok_or_else(|| bad(format!("PLY type {k}")));
                properties.push(Property::List(size(count)?, size(item)?));
            }
            ["property", kind, name] if in_vertex => {
                let size = ply_type_size(kind).ok_or_else(|| bad(format!("PLY type {kind}")))?;
                let axis = ["x", "y", "z"].iter().position(|a| a == name);
                if axis.is_some() && size != 4 {
                    return Err(bad(format!("vertex {name} is {kind}, expected float")));
                }
                properties.push(Property::Scalar(size, axis));
            }
            ["end_header"] => break,
            _ => {}
        }
    }
    let n = vertices.ok_or_else(|| bad("no vertex element".into()))?;
    let mut bytes = Vec::new();
    reader.read_to_end(&mut bytes)?;
    let short = || bad("fewer vertices than its header says".into());
    let mut at = 0usize;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let mut xyz = [f32::NAN; 3];
        for property in &properties {
            match *property {
                Property::Scalar(size, axis) => {
                    let field = bytes.get(at..at + size).ok_or_else(short)?;
                    if let Some(k) = axis {
                        xyz[k] = f32::from_le_bytes([field[0], field[1], field[2], field[3]]);
                    }
                    at += size;
                }
                Property::List(count_size, item_size) => {
                    let field = bytes.get(at..at + count_size).ok_or_else(short)?;
                    let mut count = 0usize;
                    for (i, b) in field.iter().enumerate() {
                        count |= (*b as usize) << (8 * i);
                    }
                    at += count_size + count * item_size;
                }
            }
        }
        if at > bytes.len() {
            return Err(short());
        }
        out.push(Vector3::from(xyz));
    }
    if out.iter().any(|p| p.iter().any(|c| c.is_nan())) {
        return Err(bad("the vertices lack x, y or z".into()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PLY as OpenMVS writes its dense cloud: position, colour, normal, then two lists.
    fn openmvs_like_ply(points: &[[f32; 3]], views: &[&[u32]], truncate: usize) -> Vec<u8> {
        let mut bytes = format!(
            "ply\nformat binary_little_endian 1.0\ncomment test\nelement vertex {}\n\
             property float x\nproperty float y\nproperty float z\n\
             property uchar red\nproperty uchar green\nproperty uchar blue\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             property list uint8 uint32 view_indices\nproperty list uint8 float32 view_weights\n\
             end_header\n",
            points.len()
        )
        .into_bytes();
        for (p, v) in points.iter().zip(views) {
            for c in p {
                bytes.extend(c.to_le_bytes());
            }
            bytes.extend([10, 20, 30]);
            for c in [0.0f32, 0.0, 1.0] {
                bytes.extend(c.to_le_bytes());
            }
            bytes.push(v.len() as u8);
            for i in *v {
                bytes.extend(i.to_le_bytes());
            }
            bytes.push(v.len() as u8);
            for _ in *v {
                bytes.extend(0.5f32.to_le_bytes());
            }
        }
        bytes.truncate(bytes.len() - truncate);
        bytes
    }

    #[test]
    fn positions_are_read_past_list_properties_and_a_short_file_is_an_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("dense.ply");
        let points = [[1.0f32, 2.0, 3.0], [-4.5, 5.25, 6.0], [7.0, 8.0, -9.0]];
        let views: [&[u32]; 3] = [&[0, 1, 2], &[], &[5]];
        std::fs::write(&path, openmvs_like_ply(&points, &views, 0)).expect("write");
        let read = read_ply_positions(&path).expect("read");
        let read: Vec<[f32; 3]> = read.iter().map(|p| [p.x, p.y, p.z]).collect();
        assert_eq!(read, points);
        std::fs::write(&path, openmvs_like_ply(&points, &views, 3)).expect("write");
        let error = format!("{:#}", read_ply_positions(&path).expect_err("short file"));
        assert!(error.contains("fewer vertices"), "{error}");
        std::fs::write(
            &path,
            b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n",
        )
        .expect("write");
        let error = format!("{:#}", read_ply_positions(&path).expect_err("ascii"));
        assert!(error.contains("binary_little_endian"), "{error}");
    }
}
