//! The COLMAP text model (`cameras.txt`, `images.txt`, `points3D.txt`), export and import, and the
//! conversion of camera models between COLMAP and timesift.
//!
//! Conversions (docs/design.md `brown` ↔ COLMAP): COLMAP stores the principal point in absolute pixels
//! (same pixel convention as ours), we store it as an offset from the image centre; the x focal
//! length `fx` is our `f + b1`; OpenCV's tangential `p1` is our `p2` and vice versa. `brown` cameras
//! with skew (`b2`) or an r⁸ term (`k4`) have no COLMAP equivalent and are refused rather than
//! approximated. COLMAP text has no camera names or epochs: the exporter records them in header
//! comments (`# timesift camera <id> <name>`, `# timesift image <id> <epoch>`), which COLMAP ignores
//! and the importer reads back.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use timesift_core::{BrownCamera, Camera, CameraModel, PinholeCamera, Pose};

use crate::cameras_json::{OrientedImage, Reconstruction};
use crate::{IoError, fsutil};

/// A COLMAP camera: model name and its parameter list as COLMAP orders it.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    /// COLMAP model name (`PINHOLE`, `OPENCV`, …).
    pub model: String,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Parameters in COLMAP order.
    pub params: Vec<f64>,
    /// Camera group name, when the file came from timesift.
    pub name: Option<String>,
}

/// A COLMAP image: pose, camera and 2-D points.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    /// Camera id.
    pub camera_id: u32,
    /// Image name (path relative to the project directory).
    pub name: String,
    /// `cam_from_world`.
    pub pose: Pose,
    /// Keypoints `(x, y, point3D_id)`; `-1` when not triangulated.
    pub points2d: Vec<(f64, f64, i64)>,
    /// Epoch, when the file came from timesift.
    pub epoch: Option<String>,
}

/// A COLMAP 3-D point.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapPoint {
    /// World position.
    pub xyz: Vector3<f64>,
    /// Colour.
    pub rgb: [u8; 3],
    /// Mean reprojection error, pixels.
    pub error: f64,
    /// Observations `(image_id, point2d_index)`.
    pub track: Vec<(u32, u32)>,
}

/// A COLMAP text model.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ColmapModel {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// Images by id.
    pub images: BTreeMap<u32, ColmapImage>,
    /// Points by id.
    pub points: BTreeMap<u64, ColmapPoint>,
}

/// Converts a timesift camera to a COLMAP model name and parameters.
pub fn camera_to_colmap(camera: &Camera) -> Result<(&'static str, Vec<f64>), String> {
    match camera {
        Camera::Pinhole(c) => Ok((
            "PINHOLE",
            vec![
                c.f,
                c.f,
                0.5 * c.width as f64 + c.cx,
                0.5 * c.height as f64 + c.cy,
            ],
        )),
        Camera::Brown(c) => {
            if c.b2 != 0.0 {
                return Err(format!("skew b2 = {} has no COLMAP equivalent", c.b2));
            }
            if c.k4 != 0.0 {
                return Err(format!(
                    "radial term k4 = {} (r⁸) has no COLMAP equivalent",
                    c.k4
                ));
            }
            let mut params = vec![
                c.f + c.b1,
                c.f,
                0.5 * c.width as f64 + c.cx,
                0.5 * c.height as f64 + c.cy,
                c.k1,
                c.k2,
                c.p2, // OpenCV p1
                c.p1, // OpenCV p2
            ];
            if c.k3 == 0.0 {
                Ok(("OPENCV", params))
            } else {
                params.extend([c.k3, 0.0, 0.0, 0.0]);
                Ok(("FULL_OPENCV", params))
            }
        }
    }
}

/// Converts a COLMAP camera to a timesift camera.
pub fn camera_from_colmap(
    model: &str,
    width: u32,
    height: u32,
    params: &[f64],
) -> Result<Camera, String> {
    let expected = match model {
        "SIMPLE_PINHOLE" => 3,
        "PINHOLE" | "SIMPLE_RADIAL" => 4,
        "RADIAL" => 5,
        "OPENCV" => 8,
        "FULL_OPENCV" => 12,
        other => {
            return Err(format!(
                "camera model {other} is not supported (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV are)"
            ));
        }
    };
    if params.len() != expected {
        return Err(format!(
            "{model} takes {expected} parameters, found {}",
            params.len()
        ));
    }
    let (w2, h2) = (0.5 * width as f64, 0.5 * height as f64);
    let mut c = BrownCamera {
        width,
        height,
        f: 0.0,
        cx: 0.0,
        cy: 0.0,
        b1: 0.0,
        b2: 0.0,
        k1: 0.0,
        k2: 0.0,
        k3: 0.0,
        k4: 0.0,
        p1: 0.0,
        p2: 0.0,
    };
    let pinhole = |f: f64, cx: f64, cy: f64| {
        let p = PinholeCamera {
            width,
            height,
            f,
            cx: cx - w2,
            cy: cy - h2,
        };
        p.validate()
            .map(|_| Camera::Pinhole(p))
            .map_err(|e| e.to_string())
    };
    match model {
        "SIMPLE_PINHOLE" => return pinhole(params[0], params[1], params[2]),
        "PINHOLE" if params[0] == params[1] => return pinhole(params[1], params[2], params[3]),
        "PINHOLE" => {
            c.f = params[1];
            c.b1 = params[0] - params[1];
            c.cx = params[2] - w2;
            c.cy = params[3] - h2;
        }
        "SIMPLE_RADIAL" | "RADIAL" => {
            c.f = params[0];
            c.cx = params[1] - w2;
            c.cy = params[2] - h2;
            c.k1 = params[3];
            c.k2 = params.get(4).copied().unwrap_or(0.0);
        }
        _ => {
            // OPENCV and FULL_OPENCV.
            if params.len() == 12 && params[9..12].iter().any(|&k| k != 0.0) {
                return Err(
                    "FULL_OPENCV rational terms k4, k5, k6 have no brown equivalent".to_string(),
                );
            }
            c.f = params[1];
            c.b1 = params[0] - params[1];
            c.cx = params[2] - w2;
            c.cy = params[3] - h2;
            c.k1 = params[4];
            c.k2 = params[5];
            c.p2 = params[6];
            c.p1 = params[7];
            c.k3 = params.get(8).copied().unwrap_or(0.0);
        }
    }
    c.validate()
        .map(|_| Camera::Brown(c))
        .map_err(|e| e.to_string())
}

/// The camera without the terms COLMAP has no model for (the skew `b2`, the radial `k4`), and
/// what was dropped (`"camera \"name\": skew b2 = …"`, one entry per term; empty: exact).
pub fn nearest_colmap_camera(name: &str, camera: &Camera) -> (Camera, Vec<String>) {
    let mut dropped = Vec::new();
    let mut nearest = camera.clone();
    if let Camera::Brown(c) = &mut nearest {
        if c.b2 != 0.0 {
            dropped.push(format!("camera \"{name}\": skew b2 = {} dropped", c.b2));
            c.b2 = 0.0;
        }
        if c.k4 != 0.0 {
            dropped.push(format!("camera \"{name}\": radial k4 = {} dropped", c.k4));
            c.k4 = 0.0;
        }
    }
    (nearest, dropped)
}

/// [`from_reconstruction`] with every camera COLMAP cannot hold exactly replaced by its
/// [`nearest_colmap_camera`]; the terms dropped. For outputs whose images and points matter
/// more than a copy of a camera that `cameras.json` holds exactly. Err: an image names an
/// unknown camera.
pub fn from_reconstruction_nearest(
    reconstruction: &Reconstruction,
) -> Result<(ColmapModel, Vec<String>), String> {
    let mut nearest = reconstruction.clone();
    let mut dropped = Vec::new();
    for (name, camera) in nearest.cameras.iter_mut() {
        let (c, d) = nearest_colmap_camera(name, camera);
        *camera = c;
        dropped.extend(d);
    }
    Ok((from_reconstruction(&nearest)?, dropped))
}

/// Builds the COLMAP model of a reconstruction: camera ids follow the camera names' order, image ids
/// the images' order; unoriented images are left out (COLMAP has no such state).
pub fn from_reconstruction(reconstruction: &Reconstruction) -> Result<ColmapModel, String> {
    let mut model = ColmapModel::default();
    let mut camera_ids = BTreeMap::new();
    for (index, (name, camera)) in reconstruction.cameras.iter().enumerate() {
        let id = index as u32 + 1;
        let (colmap_name, params) =
            camera_to_colmap(camera).map_err(|e| format!("camera \"{name}\": {e}"))?;
        camera_ids.insert(name.clone(), id);
        model.cameras.insert(
            id,
            ColmapCamera {
                model: colmap_name.to_string(),
                width: camera.width(),
                height: camera.height(),
                params,
                name: Some(name.clone()),
            },
        );
    }
    for (index, image) in reconstruction.images.iter().enumerate() {
        let Some(pose) = image.pose else { continue };
        let camera_id = *camera_ids.get(&image.camera).ok_or_else(|| {
            format!(
                "image \"{}\": unknown camera \"{}\"",
                image.name, image.camera
            )
        })?;
        model.images.insert(
            index as u32 + 1,
            ColmapImage {
                camera_id,
                name: image.name.clone(),
                pose,
                points2d: Vec::new(),
                epoch: Some(image.epoch.clone()),
            },
        );
    }
    Ok(model)
}

/// Converts a COLMAP model to a reconstruction. Camera names and epochs come from timesift's header
/// comments when present; otherwise cameras are named `colmap<id>` and the epoch is the first
/// folder under `images/` in the image name (or `"unknown"`).
pub fn to_reconstruction(model: &ColmapModel, crs: &str) -> Result<Reconstruction, String> {
    let mut cameras = BTreeMap::new();
    let mut names = BTreeMap::new();
    for (id, c) in &model.cameras {
        let name = c.name.clone().unwrap_or_else(|| format!("colmap{id}"));
        let camera = camera_from_colmap(&c.model, c.width, c.height, &c.params)
            .map_err(|e| format!("camera {id}: {e}"))?;
        if cameras.insert(name.clone(), camera).is_some() {
            return Err(format!("camera name \"{name}\" is used twice"));
        }
        names.insert(*id, name);
    }
    let mut images = Vec::with_capacity(model.images.len());
    for (id, img) in &model.images {
        let camera = names
            .get(&img.camera_id)
            .ok_or_else(|| format!("image {id}: unknown camera id {}", img.camera_id))?
            .clone();
        let epoch = img.epoch.clone().unwrap_or_else(|| {
            img.name
                .strip_prefix("images/")
                .and_then(|rest| rest.split_once('/'))
                .map(|(epoch, _)| epoch.to_string())
                .unwrap_or_else(|| "unknown".to_string())
        });
        images.push(OrientedImage {
            name: img.name.clone(),
            epoch,
            camera,
            pose: Some(img.pose),
        });
    }
    Ok(Reconstruction {
        crs: crs.to_string(),
        cameras,
        images,
    })
}

/// Writes `cameras.txt`, `images.txt` and `points3D.txt` into `dir`, the folder replaced as a
/// whole ([`fsutil::write_dir_atomically`]: never a new `cameras.txt` beside an old
/// `images.txt`). Numbers are written in shortest round-trip form, so nothing is lost.
pub fn write_colmap_text(dir: &Path, model: &ColmapModel) -> Result<(), IoError> {
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| IoError::io(parent, e))?;
    }
    fsutil::write_dir_atomically(dir, |tmp| write_colmap_files(tmp, model))
}

/// The three files of a model, into `dir`.
fn write_colmap_files(dir: &Path, model: &ColmapModel) -> Result<(), IoError> {
    let mut cams = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    let _ = writeln!(cams, "# Number of cameras: {}", model.cameras.len());
    for (id, c) in &model.cameras {
        if let Some(name) = &c.name {
            let _ = writeln!(cams, "# timesift camera {id} {name}");
        }
    }
    for (id, c) in &model.cameras {
        let _ = write!(cams, "{id} {} {} {}", c.model, c.width, c.height);
        for p in &c.params {
            let _ = write!(cams, " {p}");
        }
        cams.push('\n');
    }
    fsutil::write_bytes_atomically(&dir.join("cameras.txt"), cams.as_bytes())?;

    let path = dir.join("images.txt");
    fsutil::write_atomically(&path, |w| {
        let io = |e| IoError::io(&path, e);
        writeln!(w, "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: {}", model.images.len()).map_err(io)?;
        for (id, img) in &model.images {
            if let Some(epoch) = &img.epoch {
                writeln!(w, "# timesift image {id} {epoch}").map_err(io)?;
            }
        }
        for (id, img) in &model.images {
            let q = img.pose.rotation.quaternion();
            let t = img.pose.translation;
            writeln!(
                w,
                "{id} {} {} {} {} {} {} {} {} {}",
                q.w, q.i, q.j, q.k, t.x, t.y, t.z, img.camera_id, img.name
            )
            .map_err(io)?;
            let mut line = String::new();
            for (k, (x, y, p)) in img.points2d.iter().enumerate() {
                if k > 0 {
                    line.push(' ');
                }
                let _ = write!(line, "{x} {y} {p}");
            }
            writeln!(w, "{line}").map_err(io)?;
        }
        Ok(())
    })?;

    let path = dir.join("points3D.txt");
    fsutil::write_atomically(&path, |w| {
        let io = |e| IoError::io(&path, e);
        writeln!(w, "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n# Number of points: {}", model.points.len()).map_err(io)?;
        for (id, p) in &model.points {
            write!(
                w,
                "{id} {} {} {} {} {} {} {}",
                p.xyz.x, p.xyz.y, p.xyz.z, p.rgb[0], p.rgb[1], p.rgb[2], p.error
            )
            .map_err(io)?;
            for (image, idx) in &p.track {
                write!(w, " {image} {idx}").map_err(io)?;
            }
            writeln!(w).map_err(io)?;
        }
        Ok(())
    })
}

/// The lines of a COLMAP text file: data lines with their numbers, and the comments apart.
struct TextLines {
    data: Vec<(usize, String)>,
    comments: Vec<String>,
}

fn lines_of(path: &Path) -> Result<TextLines, IoError> {
    let text = fsutil::read_text(path)?;
    let mut data = Vec::new();
    let mut comments = Vec::new();
    for (i, l) in text.lines().enumerate() {
        let t = l.trim();
        if let Some(c) = t.strip_prefix('#') {
            comments.push(c.trim().to_string());
        } else {
            data.push((i + 1, l.to_string()));
        }
    }
    Ok(TextLines { data, comments })
}

fn parse<T: std::str::FromStr>(
    path: &Path,
    line: usize,
    token: Option<&str>,
    what: &str,
) -> Result<T, IoError> {
    let token = token.ok_or_else(|| IoError::line(path, line, format!("missing {what}")))?;
    // `f64::from_str` accepts `nan` and `inf`; no COLMAP field may hold them.
    let non_finite = token.parse::<f64>().is_ok_and(|v| !v.is_finite());
    token
        .parse::<T>()
        .ok()
        .filter(|_| !non_finite)
        .ok_or_else(|| {
            IoError::line(
                path,
                line,
                format!("{what}: cannot parse \"{token}\" as a finite number"),
            )
        })
}

/// Reads a COLMAP text model from `dir`. `points3D.txt` may be absent.
pub fn read_colmap_text(dir: &Path) -> Result<ColmapModel, IoError> {
    let mut model = ColmapModel::default();
    read_cameras_txt(&dir.join("cameras.txt"), &mut model.cameras)?;
    read_images_txt(&dir.join("images.txt"), &mut model.images)?;
    let path = dir.join("points3D.txt");
    if path.exists() {
        read_points3d_txt(&path, &mut model.points)?;
    }
    Ok(model)
}

/// The names timesift's comments `# <prefix><id> <name>` give to ids (camera names, image
/// epochs); other comments are ignored.
fn names_in_comments(comments: &[String], prefix: &str) -> BTreeMap<u32, String> {
    comments
        .iter()
        .filter_map(|c| {
            let rest = c.strip_prefix(prefix)?;
            let (id, name) = rest.split_once(' ')?;
            Some((id.parse().ok()?, name.to_string()))
        })
        .collect()
}

/// Reads `cameras.txt` at `path` into `cameras`; an id defined twice is an error.
fn read_cameras_txt(path: &Path, cameras: &mut BTreeMap<u32, ColmapCamera>) -> Result<(), IoError> {
    let TextLines { data, comments } = lines_of(path)?;
    let camera_names = names_in_comments(&comments, "timesift camera ");
    for (line, text) in data.iter().filter(|(_, t)| !t.trim().is_empty()) {
        let mut tok = text.split_whitespace();
        let id: u32 = parse(path, *line, tok.next(), "CAMERA_ID")?;
        let model_name: String = parse(path, *line, tok.next(), "MODEL")?;
        let width = parse(path, *line, tok.next(), "WIDTH")?;
        let height = parse(path, *line, tok.next(), "HEIGHT")?;
        let params = tok
            .map(|t| parse::<f64>(path, *line, Some(t), "PARAMS"))
            .collect::<Result<Vec<_>, _>>()?;
        if cameras.contains_key(&id) {
            return Err(IoError::line(
                path,
                *line,
                format!("camera id {id} is defined twice"),
            ));
        }
        cameras.insert(
            id,
            ColmapCamera {
                model: model_name,
                width,
                height,
                params,
                name: camera_names.get(&id).cloned(),
            },
        );
    }
    Ok(())
}

/// Reads `images.txt` at `path` into `images`: two lines an image, the second (its keypoints)
/// possibly empty; an id defined twice is an error.
fn read_images_txt(path: &Path, images: &mut BTreeMap<u32, ColmapImage>) -> Result<(), IoError> {
    let TextLines { data, comments } = lines_of(path)?;
    let epochs = names_in_comments(&comments, "timesift image ");
    let mut iter = data.iter();
    while let Some((line, text)) = iter.next() {
        if text.trim().is_empty() {
            continue;
        }
        let (id, camera_id, name, pose) = parse_image_line(path, *line, text)?;
        let mut points2d = Vec::new();
        if let Some((pline, ptext)) = iter.next() {
            points2d = parse_points2d(path, *pline, ptext)?;
        }
        if images.contains_key(&id) {
            return Err(IoError::line(
                path,
                *line,
                format!("image id {id} is defined twice"),
            ));
        }
        images.insert(
            id,
            ColmapImage {
                camera_id,
                name,
                pose,
                points2d,
                epoch: epochs.get(&id).cloned(),
            },
        );
    }
    Ok(())
}

/// An image's first line of `images.txt`: its id, camera id, name and `cam_from_world`.
fn parse_image_line(
    path: &Path,
    line: usize,
    text: &str,
) -> Result<(u32, u32, String, Pose), IoError> {
    let mut tok = text.split_whitespace();
    let id: u32 = parse(path, line, tok.next(), "IMAGE_ID")?;
    let mut v = [0.0f64; 7];
    for (k, name) in ["QW", "QX", "QY", "QZ", "TX", "TY", "TZ"]
        .iter()
        .enumerate()
    {
        v[k] = parse(path, line, tok.next(), name)?;
    }
    let camera_id = parse(path, line, tok.next(), "CAMERA_ID")?;
    // Names may contain spaces: the rest of the line.
    let name = tok.collect::<Vec<_>>().join(" ");
    if name.is_empty() {
        return Err(IoError::line(path, line, "missing NAME"));
    }
    let q = Quaternion::new(v[0], v[1], v[2], v[3]);
    if !(q.norm() > 0.5 && q.norm() < 2.0) {
        return Err(IoError::line(path, line, "quaternion is not of unit norm"));
    }
    let pose = Pose::new(
        UnitQuaternion::from_quaternion(q),
        Vector3::new(v[4], v[5], v[6]),
    );
    Ok((id, camera_id, name, pose))
}

/// An image's second line of `images.txt`: its keypoints `(x, y, point3D_id)`.
fn parse_points2d(path: &Path, pline: usize, ptext: &str) -> Result<Vec<(f64, f64, i64)>, IoError> {
    let toks: Vec<&str> = ptext.split_whitespace().collect();
    if toks.len() % 3 != 0 {
        return Err(IoError::line(
            path,
            pline,
            "POINTS2D must be triples (X, Y, POINT3D_ID)",
        ));
    }
    let mut points2d = Vec::new();
    for t in toks.chunks(3) {
        points2d.push((
            parse(path, pline, Some(t[0]), "X")?,
            parse(path, pline, Some(t[1]), "Y")?,
            parse(path, pline, Some(t[2]), "POINT3D_ID")?,
        ));
    }
    Ok(points2d)
}

/// Reads `points3D.txt` at `path` into `points`; an id defined twice is an error.
fn read_points3d_txt(path: &Path, points: &mut BTreeMap<u64, ColmapPoint>) -> Result<(), IoError> {
    let data = lines_of(path)?.data;
    for (line, text) in data.iter().filter(|(_, t)| !t.trim().is_empty()) {
        let mut tok = text.split_whitespace();
        let id: u64 = parse(path, *line, tok.next(), "POINT3D_ID")?;
        let x = parse(path, *line, tok.next(), "X")?;
        let y = parse(path, *line, tok.next(), "Y")?;
        let z = parse(path, *line, tok.next(), "Z")?;
        let rgb = [
            parse(path, *line, tok.next(), "R")?,
            parse(path, *line, tok.next(), "G")?,
            parse(path, *line, tok.next(), "B")?,
        ];
        let error = parse(path, *line, tok.next(), "ERROR")?;
        let rest: Vec<&str> = tok.collect();
        if rest.len() % 2 != 0 {
            return Err(IoError::line(
                path,
                *line,
                "TRACK must be pairs (IMAGE_ID, POINT2D_IDX)",
            ));
        }
        let track = rest
            .chunks(2)
            .map(|p| {
                Ok((
                    parse(path, *line, Some(p[0]), "IMAGE_ID")?,
                    parse(path, *line, Some(p[1]), "POINT2D_IDX")?,
                ))
            })
            .collect::<Result<Vec<_>, IoError>>()?;
        if points.contains_key(&id) {
            return Err(IoError::line(
                path,
                *line,
                format!("point id {id} is defined twice"),
            ));
        }
        points.insert(
            id,
            ColmapPoint {
                xyz: Vector3::new(x, y, z),
                rgb,
                error,
                track,
            },
        );
    }
    Ok(())
}
