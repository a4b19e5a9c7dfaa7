//! Agisoft Metashape's camera XML (File → Import → Import Cameras): sensors with their
//! frame-model calibration, cameras with their transforms, one camera group per epoch.
//!
//! docs/design.md's `brown` model *is* Metashape's frame model (f, cx, cy as offsets from the image
//! centre, b1, b2, k1–k4, p1, p2 in Metashape's order), so calibrations are written as they are.
//! A camera's `<transform>` is its `world_from_cam` 4 × 4 matrix (row-major; camera axes x right,
//! y down, z forward, as Metashape's) in the chunk's internal frame, which is the topocentric frame
//! of [`ExportFrame`]; the chunk's `<transform>` places that frame in geocentric coordinates, and
//! `<reference>` names the project CRS, so Metashape shows the block where it is.

use std::fmt::Write as _;
use std::path::Path;

use timesift_core::{Camera, CameraModel};

use crate::cameras_json::Reconstruction;
use crate::topocentric::ExportFrame;
use crate::{IoError, fsutil};

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The calibration elements of a camera, Metashape's frame model.
fn calibration(camera: &Camera) -> String {
    let (w, h) = (camera.width(), camera.height());
    let mut p = [0.0; 11];
    match camera {
        Camera::Pinhole(c) => {
            let mut q = [0.0; 3];
            c.params(&mut q);
            p[..3].copy_from_slice(&q);
        }
        Camera::Brown(c) => p = c.param_array(),
    }
    let mut s = format!(
        "<calibration type=\"frame\" class=\"adjusted\"><resolution width=\"{w}\" height=\"{h}\"/>"
    );
    for (name, value) in [
        "f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2",
    ]
    .iter()
    .zip(p)
    {
        if *name == "f" || value != 0.0 {
            let _ = write!(s, "<{name}>{value:.17e}</{name}>");
        }
    }
    s.push_str("</calibration>");
    s
}

/// The label of each image of `recon` (in order): Metashape matches imported cameras to photos by
/// label, which it takes from the file name without extension. Where two images share that stem
/// (the same file name in two epochs' folders), both are labelled with their project path
/// without extension instead, so no label is ambiguous.
pub fn camera_labels(recon: &Reconstruction) -> Vec<String> {
    let stem = |name: &str| {
        Path::new(name)
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| name.to_string())
    };
    let stems: Vec<String> = recon.images.iter().map(|i| stem(&i.name)).collect();
    recon
        .images
        .iter()
        .zip(&stems)
        .map(|(image, s)| {
            if stems.iter().filter(|t| *t == s).count() == 1 {
                s.clone()
            } else {
                let path = Path::new(&image.name);
                path.with_extension("").to_string_lossy().into_owned()
            }
        })
        .collect()
}

/// The camera XML of a reconstruction; `crs_wkt` names the project CRS for `<reference>`.
pub fn to_metashape_xml(
    recon: &Reconstruction,
    frame: &ExportFrame,
    crs_wkt: Option<&str>,
) -> Result<String, IoError> {
    let mut s = String::from(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<document version=\"1.5.0\">\n  <chunk label=\"timesift\" enabled=\"true\">\n",
    );
    let sensors: Vec<&String> = recon.cameras.keys().collect();
    let _ = writeln!(s, "    <sensors next_id=\"{}\">", sensors.len());
    for (id, name) in sensors.iter().enumerate() {
        let camera = &recon.cameras[*name];
        let _ = writeln!(
            s,
            "      <sensor id=\"{id}\" label=\"{}\" type=\"frame\"><resolution width=\"{}\" height=\"{}\"/>{}</sensor>",
            escape(name),
            camera.width(),
            camera.height(),
            calibration(camera)
        );
    }
    s.push_str("    </sensors>\n");
    let mut epochs: Vec<&str> = Vec::new();
    for image in &recon.images {
        if !epochs.contains(&image.epoch.as_str()) {
            epochs.push(&image.epoch);
        }
    }
    let _ = writeln!(
        s,
        "    <cameras next_id=\"{}\" next_group_id=\"{}\">",
        recon.images.len(),
        epochs.len()
    );
    let labels = camera_labels(recon);
    let mut camera_id = 0;
    for (group, epoch) in epochs.iter().enumerate() {
        let _ = writeln!(
            s,
            "      <group id=\"{group}\" label=\"{}\" type=\"folder\">",
            escape(epoch)
        );
        for (image, label) in recon
            .images
            .iter()
            .zip(&labels)
            .filter(|(i, _)| i.epoch == *epoch)
        {
            let sensor = sensors
                .iter()
                .position(|n| **n == image.camera)
                .unwrap_or(0);
            let _ = write!(
                s,
                "        <camera id=\"{camera_id}\" sensor_id=\"{sensor}\" label=\"{}\">",
                escape(label)
            );
            camera_id += 1;
            if let Some(pose) = &image.pose {
                let pose = frame.pose(pose)?;
                let world_from_cam = pose.inverse();
                let r = world_from_cam.rotation_matrix();
                let t = world_from_cam.translation;
                let mut m = Vec::with_capacity(16);
                for row in 0..3 {
                    m.extend([r[(row, 0)], r[(row, 1)], r[(row, 2)], t[row]]);
                }
                m.extend([0.0, 0.0, 0.0, 1.0]);
                let text: Vec<String> = m.iter().map(|v| format!("{v:.17e}")).collect();
                let _ = write!(s, "<transform>{}</transform>", text.join(" "));
            }
            s.push_str("</camera>\n");
        }
        s.push_str("      </group>\n");
    }
    s.push_str("    </cameras>\n");
    if let Some((origin, rotation)) = frame.ecef_from_frame() {
        let r: Vec<String> = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| format!("{:.17e}", rotation[(i, j)]))
            .collect();
        let _ = writeln!(
            s,
            "    <transform><rotation locked=\"true\">{}</rotation><translation locked=\"true\">{:.17e} {:.17e} {:.17e}</translation><scale locked=\"true\">1</scale></transform>",
            r.join(" "),
            origin.x,
            origin.y,
            origin.z
        );
    }
    if let Some(wkt) = crs_wkt {
        let _ = writeln!(s, "    <reference>{}</reference>", escape(wkt));
    }
    s.push_str("  </chunk>\n</document>\n");
    Ok(s)
}

/// Writes the camera XML atomically.
pub fn write_metashape_xml(
    path: &Path,
    recon: &Reconstruction,
    frame: &ExportFrame,
    crs_wkt: Option<&str>,
) -> Result<(), IoError> {
    let text = to_metashape_xml(recon, frame, crs_wkt)?;
    fsutil::write_bytes_atomically(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cameras_json::OrientedImage;
    use nalgebra::{UnitQuaternion, Vector3};
    use timesift_core::{BrownCamera, Pose};

    #[test]
    fn labels_stay_unique_and_calibrations_are_written_as_they_are() {
        let camera = Camera::Brown(BrownCamera::new(400, 300, 321.5).expect("camera"));
        let image = |name: &str, epoch: &str| OrientedImage {
            name: name.into(),
            epoch: epoch.into(),
            camera: "c".into(),
            pose: Some(Pose::from_rotation_and_center(
                UnitQuaternion::identity(),
                &Vector3::new(1.0, 2.0, 3.0),
            )),
        };
        let recon = Reconstruction {
            crs: "local".into(),
            cameras: [("c".to_string(), camera)].into(),
            images: vec![
                image("images/2019/IMG_1.jpg", "2019"),
                image("images/2020/IMG_1.jpg", "2020"),
                image("images/2020/IMG_2.jpg", "2020"),
            ],
        };
        assert_eq!(
            camera_labels(&recon),
            ["images/2019/IMG_1", "images/2020/IMG_1", "IMG_2"]
        );
        let xml = to_metashape_xml(&recon, &ExportFrame::Local, None).expect("xml");
        assert_eq!(xml.matches("<group ").count(), 2);
        assert_eq!(xml.matches("<camera ").count(), 3);
        assert!(xml.contains("<f>3.21500000000000000e2</f>"), "{xml}");
        // world_from_cam of an identity rotation centred at (1, 2, 3).
        assert!(xml.contains(
            "<transform>1.00000000000000000e0 0.00000000000000000e0 0.00000000000000000e0 1.00000000000000000e0"
        ));
        assert!(!xml.contains("<reference>") && !xml.contains("<rotation"));
    }
}
