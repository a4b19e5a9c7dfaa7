//! OpenSfM's `reconstruction.json` (and `reference_lla.json`): cameras, shots and points, as
//! OpenDroneMap and OpenSfM read them.
//!
//! Conventions converted here: OpenSfM's image coordinates are normalised — origin at the image
//! centre, the larger side 1 — so a `brown` camera's `focal_x`, `focal_y`, `c_x`, `c_y` are ours
//! divided by max(w, h) (`focal_x` = (f + b1) / s, `c_x` = cx / s). Its tangential terms follow
//! OpenCV (OpenSfM `p1` = our `p2`). A shot's `rotation` is the axis-angle vector of
//! `cam_from_world`, `translation` its t, in the topocentric frame of
//! [`crate::topocentric::ExportFrame`]. Cameras with skew (`b2`) or an r⁸ term (`k4`) have no
//! OpenSfM equivalent and are refused rather than approximated.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use serde_json::{Value, json};
use timesift_core::{Camera, CameraModel};

use crate::cameras_json::Reconstruction;
use crate::topocentric::ExportFrame;
use crate::{IoError, fsutil};

/// An OpenSfM camera (as a JSON object) for a timesift camera.
pub fn camera_to_opensfm(camera: &Camera) -> Result<Value, String> {
    let (w, h) = (camera.width(), camera.height());
    let s = w.max(h) as f64;
    match camera {
        Camera::Pinhole(c) => {
            let mut p = [0.0; 3];
            c.params(&mut p);
            // Pinhole parameters: f, cx, cy (offsets from the centre).
            Ok(json!({
                "projection_type": "brown", "width": w, "height": h,
                "focal_x": p[0] / s, "focal_y": p[0] / s, "c_x": p[1] / s, "c_y": p[2] / s,
                "k1": 0.0, "k2": 0.0, "k3": 0.0, "p1": 0.0, "p2": 0.0,
            }))
        }
        Camera::Brown(c) => {
            let [f, cx, cy, b1, b2, k1, k2, k3, k4, p1, p2] = c.param_array();
            if b2 != 0.0 || k4 != 0.0 {
                return Err(format!(
                    "OpenSfM's brown model has no skew (b2 = {b2}) nor r⁸ term (k4 = {k4})"
                ));
            }
            Ok(json!({
                "projection_type": "brown", "width": w, "height": h,
                "focal_x": (f + b1) / s, "focal_y": f / s, "c_x": cx / s, "c_y": cy / s,
                "k1": k1, "k2": k2, "k3": k3, "p1": p2, "p2": p1,
            }))
        }
    }
}

/// The reconstruction in OpenSfM's format: one reconstruction holding every oriented image,
/// with `points` (world position, RGB) converted into the same frame. Camera ids are the
/// camera-group names.
pub fn to_opensfm(
    recon: &Reconstruction,
    points: &[(Vector3<f64>, [u8; 3])],
    frame: &ExportFrame,
) -> Result<Value, String> {
    let mut cameras = serde_json::Map::new();
    for (name, camera) in &recon.cameras {
        cameras.insert(
            name.clone(),
            camera_to_opensfm(camera).map_err(|e| format!("camera {name}: {e}"))?,
        );
    }
    let mut shots = serde_json::Map::new();
    for image in &recon.images {
        let Some(pose) = &image.pose else { continue };
        let pose = frame.pose(pose).map_err(|e| e.to_string())?;
        let r = pose.rotation.scaled_axis();
        shots.insert(
            image.name.clone(),
            json!({
                "camera": image.camera,
                "rotation": [r.x, r.y, r.z],
                "translation": [pose.translation.x, pose.translation.y, pose.translation.z],
                "gps_dop": 999999.0,
                "orientation": 1,
                "capture_time": 0.0,
            }),
        );
    }
    let mut out_points = serde_json::Map::new();
    for (i, (p, rgb)) in points.iter().enumerate() {
        let q = frame.point(p).map_err(|e| e.to_string())?;
        out_points.insert(
            i.to_string(),
            json!({"coordinates": [q.x, q.y, q.z], "color": [rgb[0], rgb[1], rgb[2]]}),
        );
    }
    let mut reconstruction = json!({
        "cameras": cameras,
        "shots": shots,
        "points": out_points,
        "biases": {},
        "rig_cameras": {},
        "rig_instances": {},
    });
    if let Some([lat, lon, alt]) = frame.reference() {
        reconstruction["reference_lla"] =
            json!({"latitude": lat, "longitude": lon, "altitude": alt});
    }
    Ok(Value::Array(vec![reconstruction]))
}

/// Writes `reconstruction.json` (and `reference_lla.json` for a georeferenced block) into `dir`.
pub fn write_opensfm(
    dir: &Path,
    recon: &Reconstruction,
    points: &[(Vector3<f64>, [u8; 3])],
    frame: &ExportFrame,
) -> Result<Vec<std::path::PathBuf>, IoError> {
    let path = dir.join("reconstruction.json");
    let value = to_opensfm(recon, points, frame).map_err(|e| IoError::invalid(&path, e))?;
    let mut written = vec![path.clone()];
    write_json(&path, &value)?;
    if let Some([lat, lon, alt]) = frame.reference() {
        let lla = dir.join("reference_lla.json");
        write_json(
            &lla,
            &json!({"latitude": lat, "longitude": lon, "altitude": alt}),
        )?;
        written.push(lla);
    }
    Ok(written)
}

fn write_json(path: &Path, value: &Value) -> Result<(), IoError> {
    let text =
        serde_json::to_string_pretty(value).map_err(|e| IoError::invalid(path, e.to_string()))?;
    fsutil::write_bytes_atomically(path, text.as_bytes())
}

/// Pixel position (our convention) of a normalised OpenSfM `brown` projection of a point given
/// in the camera frame: the reading side of [`camera_to_opensfm`], used to check exports.
pub fn project_opensfm(
    camera: &BTreeMap<String, f64>,
    w: f64,
    h: f64,
    p_cam: &Vector3<f64>,
) -> [f64; 2] {
    let g = |k: &str| camera.get(k).copied().unwrap_or(0.0);
    let (x, y) = (p_cam.x / p_cam.z, p_cam.y / p_cam.z);
    let r2 = x * x + y * y;
    let radial = 1.0 + g("k1") * r2 + g("k2") * r2 * r2 + g("k3") * r2 * r2 * r2;
    let xd = x * radial + 2.0 * g("p1") * x * y + g("p2") * (r2 + 2.0 * x * x);
    let yd = y * radial + g("p1") * (r2 + 2.0 * y * y) + 2.0 * g("p2") * x * y;
    let s = w.max(h);
    [
        w / 2.0 + s * (g("focal_x") * xd + g("c_x")),
        h / 2.0 + s * (g("focal_y") * yd + g("c_y")),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use timesift_core::BrownCamera;

    #[test]
    fn opensfm_brown_projects_like_ours() {
        let mut c = BrownCamera::new(4000, 3000, 2900.0).expect("camera");
        // f, cx, cy, b1, b2, k1, k2, k3, k4, p1, p2
        c.set_params(&[
            2900.0, 12.5, -8.0, 3.0, 0.0, -0.11, 0.05, -0.01, 0.0, 4e-4, -2e-4,
        ])
        .expect("params");
        let camera = Camera::Brown(c);
        let v = camera_to_opensfm(&camera).expect("convertible");
        let params: BTreeMap<String, f64> = v
            .as_object()
            .expect("object")
            .iter()
            .filter_map(|(k, v)| Some((k.clone(), v.as_f64()?)))
            .collect();
        for p in [
            Vector3::new(0.3, -0.2, 1.0),
            Vector3::new(-0.45, 0.33, 1.2),
            Vector3::new(0.01, 0.02, 3.0),
        ] {
            let ours = camera.project(&p).expect("project");
            let theirs = project_opensfm(&params, 4000.0, 3000.0, &p);
            assert!(
                (ours.x - theirs[0]).abs() < 1e-9 && (ours.y - theirs[1]).abs() < 1e-9,
                "{ours:?} vs {theirs:?}"
            );
        }
        let mut skewed = BrownCamera::new(400, 300, 290.0).expect("camera");
        skewed
            .set_params(&[290.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            .expect("params");
        assert!(camera_to_opensfm(&Camera::Brown(skewed)).is_err());
    }
}
