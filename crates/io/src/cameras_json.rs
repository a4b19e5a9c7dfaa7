//! `cameras.json`: the orientation result (and the ground truth written by `synth`), schema of
//! docs/design.md. Images that could not be oriented carry `"R": null`.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use timesift_core::{BrownCamera, Camera, PinholeCamera, Pose};

use crate::{IoError, fsutil};

/// An orientation result: cameras by group name, and every image with its pose when oriented.
#[derive(Debug, Clone, PartialEq)]
pub struct Reconstruction {
    /// The world frame, e.g. `"EPSG:32755"` or `"local"`.
    pub crs: String,
    /// Camera groups by name.
    pub cameras: BTreeMap<String, Camera>,
    /// All images, oriented or not.
    pub images: Vec<OrientedImage>,
}

/// One image of a [`Reconstruction`].
#[derive(Debug, Clone, PartialEq)]
pub struct OrientedImage {
    /// Path relative to the project directory.
    pub name: String,
    /// Epoch name.
    pub epoch: String,
    /// Camera group name (a key of [`Reconstruction::cameras`]).
    pub camera: String,
    /// `cam_from_world`, or `None` when the image could not be oriented.
    pub pose: Option<Pose>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileJson {
    crs: String,
    cameras: BTreeMap<String, CameraJson>,
    images: Vec<ImageJson>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraJson {
    model: String,
    width: u32,
    height: u32,
    f: f64,
    #[serde(default)]
    cx: f64,
    #[serde(default)]
    cy: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    b1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    b2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k3: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k4: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    p1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    p2: Option<f64>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImageJson {
    name: String,
    epoch: String,
    camera: String,
    #[serde(rename = "R")]
    r: Option<[[f64; 3]; 3]>,
    t: Option<[f64; 3]>,
    #[serde(default)]
    center: Option<[f64; 3]>,
}

fn camera_to_json(camera: &Camera) -> CameraJson {
    match camera {
        Camera::Brown(c) => CameraJson {
            model: "brown".into(),
            width: c.width,
            height: c.height,
            f: c.f,
            cx: c.cx,
            cy: c.cy,
            b1: Some(c.b1),
            b2: Some(c.b2),
            k1: Some(c.k1),
            k2: Some(c.k2),
            k3: Some(c.k3),
            k4: Some(c.k4),
            p1: Some(c.p1),
            p2: Some(c.p2),
        },
        Camera::Pinhole(c) => CameraJson {
            model: "pinhole".into(),
            width: c.width,
            height: c.height,
            f: c.f,
            cx: c.cx,
            cy: c.cy,
            b1: None,
            b2: None,
            k1: None,
            k2: None,
            k3: None,
            k4: None,
            p1: None,
            p2: None,
        },
    }
}

fn camera_from_json(path: &Path, name: &str, j: &CameraJson) -> Result<Camera, IoError> {
    let key = format!("cameras.{name}");
    let bad = |e: timesift_core::CoreError| IoError::key(path, &key, e.to_string());
    match j.model.as_str() {
        "brown" => {
            let c = BrownCamera {
                width: j.width,
                height: j.height,
                f: j.f,
                cx: j.cx,
                cy: j.cy,
                b1: j.b1.unwrap_or(0.0),
                b2: j.b2.unwrap_or(0.0),
                k1: j.k1.unwrap_or(0.0),
                k2: j.k2.unwrap_or(0.0),
                k3: j.k3.unwrap_or(0.0),
                k4: j.k4.unwrap_or(0.0),
                p1: j.p1.unwrap_or(0.0),
                p2: j.p2.unwrap_or(0.0),
            };
            c.validate().map_err(bad)?;
            Ok(Camera::Brown(c))
        }
        "pinhole" => {
            let distortion = [j.b1, j.b2, j.k1, j.k2, j.k3, j.k4, j.p1, j.p2];
            if distortion.iter().any(|v| v.is_some_and(|v| v != 0.0)) {
                return Err(IoError::key(
                    path,
                    &key,
                    "a pinhole camera has no distortion terms; use model \"brown\"",
                ));
            }
            let c = PinholeCamera {
                width: j.width,
                height: j.height,
                f: j.f,
                cx: j.cx,
                cy: j.cy,
            };
            c.validate().map_err(bad)?;
            Ok(Camera::Pinhole(c))
        }
        other => Err(IoError::key(
            path,
            format!("{key}.model"),
            format!("expected \"brown\" or \"pinhole\", found \"{other}\""),
        )),
    }
}

/// Serialises a reconstruction to the JSON text of `cameras.json`.
pub fn to_json_string(reconstruction: &Reconstruction) -> String {
    let file = FileJson {
        crs: reconstruction.crs.clone(),
        cameras: reconstruction
            .cameras
            .iter()
            .map(|(k, c)| (k.clone(), camera_to_json(c)))
            .collect(),
        images: reconstruction
            .images
            .iter()
            .map(|img| {
                let (r, t, center) = match &img.pose {
                    Some(p) => {
                        let m = p.rotation_matrix();
                        let c = p.center();
                        (
                            Some([
                                [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
                                [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
                                [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
                            ]),
                            Some([p.translation.x, p.translation.y, p.translation.z]),
                            Some([c.x, c.y, c.z]),
                        )
                    }
                    None => (None, None, None),
                };
                ImageJson {
                    name: img.name.clone(),
                    epoch: img.epoch.clone(),
                    camera: img.camera.clone(),
                    r,
                    t,
                    center,
                }
            })
            .collect(),
    };
    // Serialising plain structs of strings and finite-or-not floats cannot fail; non-finite
    // floats become null, which the reader rejects.
    serde_json::to_string_pretty(&file).unwrap_or_default()
}

/// Writes `cameras.json` atomically.
pub fn write_cameras_json(path: &Path, reconstruction: &Reconstruction) -> Result<(), IoError> {
    let mut text = to_json_string(reconstruction);
    text.push('\n');
    fsutil::write_bytes_atomically(path, text.as_bytes())
}

/// Reads and validates `cameras.json`: rotations must be rotations, `t` and `R` come together,
/// every image names a known camera.
pub fn read_cameras_json(path: &Path) -> Result<Reconstruction, IoError> {
    let text = fsutil::read_text(path)?;
    let file: FileJson = serde_json::from_str(&text)
        .map_err(|e| IoError::line(path, e.line(), format!("invalid cameras.json: {e}")))?;
    let mut cameras = BTreeMap::new();
    for (name, j) in &file.cameras {
        cameras.insert(name.clone(), camera_from_json(path, name, j)?);
    }
    let mut images = Vec::with_capacity(file.images.len());
    for (i, j) in file.images.into_iter().enumerate() {
        if !cameras.contains_key(&j.camera) {
            return Err(IoError::key(
                path,
                format!("images[{i}].camera"),
                format!("unknown camera \"{}\"", j.camera),
            ));
        }
        let pose = match (j.r, j.t) {
            (Some(r), Some(t)) => {
                if !t.iter().all(|v| v.is_finite()) {
                    return Err(IoError::key(
                        path,
                        format!("images[{i}].t"),
                        "non-finite translation",
                    ));
                }
                let m = Matrix3::from_fn(|row, col| r[row][col]);
                let pose = Pose::from_rt(&m, &Vector3::from(t))
                    .map_err(|e| IoError::key(path, format!("images[{i}].R"), e.to_string()))?;
                // `center` is redundant with R and t; when given it must agree with them.
                if let Some(c) = j.center {
                    let c = Vector3::from(c);
                    let expected = pose.center();
                    if !((c - expected).norm() <= 1e-6 + 1e-12 * expected.norm()) {
                        return Err(IoError::key(
                            path,
                            format!("images[{i}].center"),
                            format!("does not equal −Rᵀt = {expected:?}"),
                        ));
                    }
                }
                Some(pose)
            }
            (None, None) => None,
            _ => {
                return Err(IoError::key(
                    path,
                    format!("images[{i}]"),
                    "`R` and `t` must both be given or both be null",
                ));
            }
        };
        images.push(OrientedImage {
            name: j.name,
            epoch: j.epoch,
            camera: j.camera,
            pose,
        });
    }
    Ok(Reconstruction {
        crs: file.crs,
        cameras,
        images,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    pub(crate) fn sample() -> Reconstruction {
        let mut brown = BrownCamera::new(4000, 3000, 2900.0).unwrap();
        brown.k1 = -0.05;
        brown.p2 = 1e-4;
        let mut cameras = BTreeMap::new();
        cameras.insert("2018-06".to_string(), Camera::Brown(brown));
        cameras.insert(
            "scan".to_string(),
            Camera::Pinhole(PinholeCamera::new(1000, 800, 1500.0).unwrap()),
        );
        Reconstruction {
            crs: "EPSG:32755".into(),
            cameras,
            images: vec![
                OrientedImage {
                    name: "images/2018-06/IMG_0001.jpg".into(),
                    epoch: "2018-06".into(),
                    camera: "2018-06".into(),
                    pose: Some(Pose::new(
                        UnitQuaternion::from_euler_angles(0.1, 3.0, -0.4),
                        Vector3::new(512345.25, 5812345.5, 101.0),
                    )),
                },
                OrientedImage {
                    name: "images/1970/scan.tif".into(),
                    epoch: "1970".into(),
                    camera: "scan".into(),
                    pose: None,
                },
            ],
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cameras.json");
        let r = sample();
        write_cameras_json(&p, &r).unwrap();
        let back = read_cameras_json(&p).unwrap();
        assert_eq!(back.cameras, r.cameras);
        assert_eq!(back.images[1].pose, None);
        let (a, b) = (r.images[0].pose.unwrap(), back.images[0].pose.unwrap());
        assert!((a.rotation_matrix() - b.rotation_matrix()).amax() < 1e-15);
        assert_eq!(a.translation, b.translation);
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.contains("\"R\": null"));
    }

    #[test]
    fn errors_name_the_key() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cameras.json");
        let mut text = to_json_string(&sample());
        text = text.replace("\"camera\": \"scan\"", "\"camera\": \"nope\"");
        std::fs::write(&p, &text).unwrap();
        let e = read_cameras_json(&p).unwrap_err().to_string();
        assert!(e.contains("images[1].camera") && e.contains("nope"), "{e}");
        std::fs::write(
            &p,
            "{\"crs\": \"local\", \"cameras\": {}, \"images\": [], \"extra\": 1}",
        )
        .unwrap();
        let e = read_cameras_json(&p).unwrap_err().to_string();
        assert!(e.contains("extra") && e.contains("line 1"), "{e}");
        // A `center` that disagrees with R and t is refused, by key.
        let mut r = sample();
        r.images.truncate(1);
        let mut v: serde_json::Value = serde_json::from_str(&to_json_string(&r)).unwrap();
        let cx = v["images"][0]["center"][0].as_f64().unwrap();
        v["images"][0]["center"][0] = serde_json::json!(cx + 1.0);
        std::fs::write(&p, v.to_string()).unwrap();
        let e = read_cameras_json(&p).unwrap_err().to_string();
        assert!(e.contains("images[0].center"), "{e}");
    }
}
