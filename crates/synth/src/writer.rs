//! Writes a [`SceneSpec`] as a project directory of docs/design.md plus `truth/`:
//!
//! ```text
//! project.toml, images/<epoch>/IMG_nnnn.*, gcps.csv, checkpoints.csv, markers.csv, stable_points.csv,
//! gnss.csv (when the scene has GNSS), stable.csv (ground scenes), scalebars.csv (when any)
//! truth/cameras.json     true cameras and poses (world frame)
//! truth/points.csv       exact world positions of every GCP, check point and scale-bar target
//! truth/stable_points.csv exact world positions of the natural stable points (stable_points.csv
//!                        names them; markers.csv measures them in every epoch, for `manual`)
//! truth/dem_<epoch>.tif  true surface per epoch on the scene grid (wall scenes: wall frame)
//! truth/surface_<epoch>.ply  the rendered surface mesh (wall scenes)
//! truth/stable.tif       1 where the surface and its cover never change, 0 elsewhere
//! truth/change.json      regions with their true volumes between every pair of epochs
//! truth/gnss_bias.csv    each epoch's GNSS bias (gnss.csv minus the true centres, less noise)
//! truth/fiducials.csv    film scans: the true scan pixel of every fiducial mark of every scan
//! truth/scan_transforms.csv  film scans: each scan's affine frame → scan pixels (a11 … a23)
//! calibration/mark_<epoch>.png  film scans: the mark template a user would cut from a scan
//! ```
//!
//! For film epochs the images are scans (see `film`): the truth cameras describe the
//! photograph in frame pixels, markers.csv is measured on the scans.
//!
//! Images are rendered one at a time (each with every core) and written as they come, so memory
//! holds one epoch's scene and one image, whatever the block size.

use std::fmt::Write as _;
use std::io::Cursor;
use std::path::Path;

use nalgebra::{Vector2, Vector3};
use serde_json::json;
use timesift_core::{BrownCamera, Camera, CameraModel, Pose, SeededRng, project_world};
use timesift_io::cameras_json::{OrientedImage, Reconstruction, write_cameras_json};
use timesift_io::coords::Crs;
use timesift_io::fsutil::write_bytes_atomically;
use timesift_io::geotiff::{GeoRaster, GeoReference, GeoTransform, write_f32};
use timesift_io::wkt::ring_contains;

use crate::SynthError;
use crate::effects::{self, Channels};
use crate::film::{FilmSpec, FrameRays, ScanCamera, ScanGeometry};
use crate::render::{RayTable, RgbImage, Scene, render_rays};
use crate::scene::{EpochSpec, Frame, ImageFormat, ImageSpec, NamedPoint, SceneSpec};
use crate::terrain::Heightfield;
use timesift_io::exif::{CameraTags, jpeg_with_camera_tags};

/// What to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteOptions {
    /// Render and write the images (everything else is cheap; tests of geometry skip this).
    pub images: bool,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions { images: true }
    }
}

/// What was written.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// Images (written or, without `images`, described in truth/cameras.json).
    pub images: usize,
    /// Marker observations.
    pub markers: usize,
    /// Megapixels rendered.
    pub megapixels: f64,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> SynthError {
    SynthError::Write(format!("{}: {e}", path.display()))
}

fn write_text(path: &Path, text: &str) -> Result<(), SynthError> {
    write_bytes_atomically(path, text.as_bytes()).map_err(|e| SynthError::Write(e.to_string()))
}

/// Image path of image `k` of `epoch`, relative to the project.
pub fn image_name(spec: &SceneSpec, epoch: usize, k: usize) -> String {
    let e = &spec.epochs[epoch];
    format!(
        "images/{}/IMG_{:04}.{}",
        e.name,
        k + 1,
        e.format.extension()
    )
}

/// `cam_from_world` of a `cam_from_local` pose, world = local + origin.
fn world_pose(pose: &Pose, origin: &Vector3<f64>) -> Pose {
    Pose::new(pose.rotation, pose.translation - pose.rotation * origin)
}

/// Surface normal of the heightfield at a grid position, in the local frame.
fn normal(spec: &SceneSpec, field: &Heightfield, at: (f64, f64)) -> Vector3<f64> {
    let h = field.cell;
    let z = |x: f64, y: f64| field.height_at(x, y).unwrap_or(0.0);
    let dx = (z(at.0 + h, at.1) - z(at.0 - h, at.1)) / (2.0 * h);
    let dy = (z(at.0, at.1 + h) - z(at.0, at.1 - h)) / (2.0 * h);
    let n = Vector3::new(-dx, -dy, 1.0).normalize();
    spec.frame.to_local(n.x, n.y, n.z)
}

/// Writes the scene into `dir` (created; existing files are replaced).
pub fn write_scene(
    spec: &SceneSpec,
    dir: &Path,
    options: &WriteOptions,
) -> Result<Written, SynthError> {
    validate(spec)?;
    std::fs::create_dir_all(dir.join("truth")).map_err(|e| io_err(dir, e))?;
    let mut rng = SeededRng::new(spec.seed ^ 0x5EED_0F7A_7750);
    let crs: Crs = spec
        .crs
        .parse()
        .map_err(|e: String| SynthError::InvalidScene(e))?;
    // Natural stable points: every candidate is observed as a target would be; those the
    // cameras see enough are kept after the last epoch.
    let candidates = spec.natural_candidates();
    let mut records = Records::new(candidates.len());
    for (e, epoch) in spec.epochs.iter().enumerate() {
        let field = spec.heightfield(e);
        let (targets, naturals) = epoch_points(spec, &field, &candidates)?;
        if e == 0 {
            records.candidate_local = naturals.iter().map(|(x, _)| *x).collect();
            records.points_local.extend(
                targets
                    .iter()
                    .map(|(kind, p, x, _)| (p.name.clone(), *kind, *x)),
            );
        }
        let scene = spec.scene(&field, e)?;
        write_true_surface(spec, &field, e, crs, dir)?;
        let bias = Vector3::new(rng.normal(), rng.normal(), rng.normal());
        let (frame_rays, rays) = epoch_rays(dir, epoch, options)?;
        let view = EpochView {
            spec,
            dir,
            options,
            e,
            epoch,
            scene,
            targets,
            naturals,
            bias,
            frame_rays,
            rays,
        };
        for (k, image) in epoch.images.iter().enumerate() {
            write_image(&view, k, image, &mut records, &mut rng)?;
        }
    }
    write_records(spec, dir, crs, &candidates, records, &mut rng)
}

/// What the images of every epoch add up to, written once the last epoch is done: the CSV
/// texts of the observations and of the truth, the true images, the counts, and the named and
/// natural points' local positions (first epoch) with every natural candidate's measurements
/// (image, epoch, pixel).
struct Records {
    markers: String,
    gnss: String,
    gnss_bias: String,
    truth_marks: String,
    truth_scans: String,
    truth_images: Vec<OrientedImage>,
    written: Written,
    points_local: Vec<(String, &'static str, Vector3<f64>)>,
    candidate_local: Vec<Vector3<f64>>,
    candidate_seen: Vec<Vec<(String, usize, Vector2<f64>)>>,
}

impl Records {
    /// Nothing recorded yet (the CSV headers only), for `candidates` natural candidates.
    fn new(candidates: usize) -> Records {
        Records {
            markers: String::from("image,name,u,v\n"),
            gnss: String::from("image,x,y,z,sxy,sz\n"),
            gnss_bias: String::from("epoch,east,north,up\n"),
            truth_marks: String::from("image,mark,u,v\n"),
            truth_scans: String::from("image,a11,a12,a13,a21,a22,a23\n"),
            truth_images: Vec::new(),
            written: Written {
                images: 0,
                markers: 0,
                megapixels: 0.0,
            },
            points_local: Vec::new(),
            candidate_local: Vec::new(),
            candidate_seen: vec![Vec::new(); candidates],
        }
    }
}

/// A named point in an epoch: its kind, the point, its local position and surface normal.
type LocatedPoint<'a> = (&'static str, &'a NamedPoint, Vector3<f64>, Vector3<f64>);
/// A local position on the surface and the surface normal there.
type PositionNormal = (Vector3<f64>, Vector3<f64>);

/// One epoch as its images are written: where and what to write, the epoch, its rendered
/// scene, its named points and natural candidates (local position, normal), the GNSS bias drawn
/// for it, and the rays of its camera (of the photograph, for film scans).
struct EpochView<'a> {
    spec: &'a SceneSpec,
    dir: &'a Path,
    options: &'a WriteOptions,
    e: usize,
    epoch: &'a EpochSpec,
    scene: Scene,
    targets: Vec<LocatedPoint<'a>>,
    naturals: Vec<PositionNormal>,
    bias: Vector3<f64>,
    frame_rays: Option<FrameRays>,
    rays: RayTable,
}

/// Every named point with its position and surface normal on the epoch's `field`, and the
/// same of every natural candidate (which must all lie on the grid).
fn epoch_points<'a>(
    spec: &'a SceneSpec,
    field: &Heightfield,
    candidates: &[(f64, f64)],
) -> Result<(Vec<LocatedPoint<'a>>, Vec<PositionNormal>), SynthError> {
    let targets = spec
        .named_points()
        .map(|(kind, p)| {
            let x = spec.point_local(field, p)?;
            Ok((kind, p, x, normal(spec, field, p.at)))
        })
        .collect::<Result<Vec<_>, SynthError>>()?;
    let naturals: Vec<PositionNormal> = candidates
        .iter()
        .filter_map(|&(x, y)| {
            let h = field.height_at(x, y)?;
            Some((spec.frame.to_local(x, y, h), normal(spec, field, (x, y))))
        })
        .collect();
    if naturals.len() != candidates.len() {
        return Err(SynthError::InvalidScene(
            "a natural stable point candidate lies outside the grid".into(),
        ));
    }
    Ok((targets, naturals))
}

/// Writes the true surface of epoch `e`: its DEM, and for wall scenes its mesh.
fn write_true_surface(
    spec: &SceneSpec,
    field: &Heightfield,
    e: usize,
    crs: Crs,
    dir: &Path,
) -> Result<(), SynthError> {
    let epoch = &spec.epochs[e];
    write_dem(
        spec,
        field,
        e,
        crs,
        &dir.join(format!("truth/dem_{}.tif", epoch.name)),
    )?;
    if spec.frame == Frame::Wall {
        write_ply(
            spec,
            field,
            &dir.join(format!("truth/surface_{}.ply", epoch.name)),
        )?;
    }
    Ok(())
}

/// The rays an epoch's images are rendered with: for film, the photograph's (the scans' own
/// are made per scan), else the camera's at the epoch's supersampling; empty tables without
/// images. Writes a film epoch's mark template.
fn epoch_rays(
    dir: &Path,
    epoch: &EpochSpec,
    options: &WriteOptions,
) -> Result<(Option<FrameRays>, RayTable), SynthError> {
    let frame_rays = match (&epoch.film, options.images) {
        (Some(film), true) => {
            write_template(dir, &epoch.name, film)?;
            Some(FrameRays::new(&epoch.camera))
        }
        (Some(film), false) => {
            write_template(dir, &epoch.name, film)?;
            None
        }
        _ => None,
    };
    let rays = if options.images && epoch.film.is_none() {
        RayTable::new(
            &epoch.camera,
            epoch.camera.width as usize,
            epoch.camera.height as usize,
            epoch.supersampling,
        )
    } else {
        RayTable::new(&epoch.camera, 0, 0, 1)
    };
    Ok((frame_rays, rays))
}

/// Image `k` of the epoch: its markers, GNSS, film truth and (with `images`) the image file,
/// recorded in `records`; `rng` gives the marker and GNSS noise.
fn write_image(
    view: &EpochView<'_>,
    k: usize,
    image: &ImageSpec,
    records: &mut Records,
    rng: &mut SeededRng,
) -> Result<(), SynthError> {
    let epoch = view.epoch;
    let name = image_name(view.spec, view.e, k);
    let scan = epoch.film.as_ref().map(|film| {
        let mut rng = SeededRng::new(image.effects.seed ^ 0x5CA7_F11E);
        film.draw_scan(&epoch.camera, &mut rng)
    });
    record_markers(view, &name, image, scan.as_ref(), records, rng)?;
    record_gnss(view, k, &name, image, records, rng)?;
    if let (Some(film), Some(scan)) = (&epoch.film, &scan) {
        record_scan_truth(film, scan, &epoch.camera, &name, records);
    }
    if view.options.images {
        records.written.megapixels += render_image(view, &name, image, scan.as_ref())?;
    }
    records.truth_images.push(OrientedImage {
        name,
        epoch: epoch.name.clone(),
        camera: epoch.name.clone(),
        pose: Some(world_pose(&image.pose, &view.spec.origin)),
    });
    records.written.images += 1;
    Ok(())
}

/// Measures the epoch's points in image `name`: a marker with noise from `rng` for every named
/// point seen, the pixel of every natural candidate seen kept for later. On film, points are
/// measured on the scan, and only on the photograph.
fn record_markers(
    view: &EpochView<'_>,
    name: &str,
    image: &ImageSpec,
    scan: Option<&ScanGeometry>,
    records: &mut Records,
    rng: &mut SeededRng,
) -> Result<(), SynthError> {
    let epoch = view.epoch;
    let measured = |x: &Vector3<f64>, n: &Vector3<f64>| {
        let seen = observe(&view.scene, &epoch.camera, &image.pose, x, n);
        match (&epoch.film, scan) {
            (Some(film), Some(scan)) => seen
                .filter(|px| film.on_photo(&epoch.camera, &(px.add_scalar(4.0))))
                .filter(|px| film.on_photo(&epoch.camera, &(px.add_scalar(-4.0))))
                .map(|px| scan.scan_px(&px)),
            _ => seen,
        }
    };
    for (_, p, x, n) in &view.targets {
        if let Some(px) = measured(x, n) {
            let noisy = px
                + Vector2::new(truncated_normal(rng), truncated_normal(rng))
                    * view.spec.marker_sigma;
            records.written.markers += 1;
            writeln!(
                records.markers,
                "{name},{},{:.3},{:.3}",
                p.name, noisy.x, noisy.y
            )
            .map_err(|e| SynthError::Write(e.to_string()))?;
        }
    }
    for (k, (x, n)) in view.naturals.iter().enumerate() {
        if let Some(px) = measured(x, n) {
            records.candidate_seen[k].push((name.to_string(), view.e, px));
        }
    }
    Ok(())
}

/// The GNSS of image `k` (when the scene has GNSS): the epoch's bias with its first image, the
/// camera centre with the bias and noise from `rng`.
fn record_gnss(
    view: &EpochView<'_>,
    k: usize,
    name: &str,
    image: &ImageSpec,
    records: &mut Records,
    rng: &mut SeededRng,
) -> Result<(), SynthError> {
    let (spec, bias) = (view.spec, view.bias);
    if let (Some(g), 0) = (&spec.gnss, k) {
        let _ = writeln!(
            records.gnss_bias,
            "{},{:.6},{:.6},{:.6}",
            view.epoch.name,
            g.bias_h * bias.x,
            g.bias_h * bias.y,
            g.bias_v * bias.z
        );
    }
    if let Some(g) = &spec.gnss {
        let c = image.pose.center() + spec.origin;
        let x = c.x + g.bias_h * bias.x + g.noise_h * rng.normal();
        let y = c.y + g.bias_h * bias.y + g.noise_h * rng.normal();
        let z = c.z + g.bias_v * bias.z + g.noise_v * rng.normal();
        let (sxy, sz) = (g.bias_h.hypot(g.noise_h), g.bias_v.hypot(g.noise_v));
        writeln!(records.gnss, "{name},{x:.3},{y:.3},{z:.3},{sxy:.2},{sz:.2}")
            .map_err(|e| SynthError::Write(e.to_string()))?;
    }
    Ok(())
}

/// The truth of scan `name`: the scan pixel of every fiducial mark, the scan's transform.
fn record_scan_truth(
    film: &FilmSpec,
    scan: &ScanGeometry,
    camera: &BrownCamera,
    name: &str,
    records: &mut Records,
) {
    for (k, (mark, _)) in film.marks.iter().enumerate() {
        let px = scan.scan_px(&film.marks_px(camera)[k]);
        let _ = writeln!(records.truth_marks, "{name},{mark},{:.4},{:.4}", px.x, px.y);
    }
    let m = scan.scan_from_frame;
    let _ = writeln!(
        records.truth_scans,
        "{name},{:.9},{:.9},{:.6},{:.9},{:.9},{:.6}",
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)]
    );
}

/// Renders image `name` (a scan, on film) with its effects and writes it, JPEG with the
/// camera's EXIF; returns the megapixels rendered.
fn render_image(
    view: &EpochView<'_>,
    name: &str,
    image: &ImageSpec,
    scan: Option<&ScanGeometry>,
) -> Result<f64, SynthError> {
    let epoch = view.epoch;
    let path = view.dir.join(name);
    let (rendered, (width, height)) = match (&epoch.film, scan, &view.frame_rays) {
        (Some(film), Some(scan), Some(frame_rays)) => {
            render_scan(&view.scene, epoch, film, scan, frame_rays, &image.pose)
        }
        _ => (
            render_rays(&view.scene, &view.rays, &image.pose, epoch.shadows),
            (epoch.camera.width, epoch.camera.height),
        ),
    };
    let pixels = effects::apply(&rendered, &image.effects);
    let mut bytes = encode(&pixels, width, height, image.effects.channels, epoch.format)
        .map_err(|e| io_err(&path, e))?;
    if let ImageFormat::Jpeg(_) = epoch.format {
        bytes = jpeg_with_camera_tags(&bytes, &camera_tags(&epoch.camera), &path)
            .map_err(|e| SynthError::Write(e.to_string()))?;
    }
    write_bytes_atomically(&path, &bytes).map_err(|e| SynthError::Write(e.to_string()))?;
    Ok((width * height) as f64 / 1e6)
}

/// Writes what the epochs recorded (markers with the natural points', GNSS, film truth, the
/// surveyed points with survey noise from `rng`, the true cameras) and the files that depend
/// on the scene alone; returns the counts.
fn write_records(
    spec: &SceneSpec,
    dir: &Path,
    crs: Crs,
    candidates: &[(f64, f64)],
    mut records: Records,
    rng: &mut SeededRng,
) -> Result<Written, SynthError> {
    records.written.markers += write_natural_points(
        spec,
        candidates,
        &records.candidate_local,
        &records.candidate_seen,
        &mut records.markers,
        dir,
    )?;
    write_text(&dir.join("markers.csv"), &records.markers)?;
    if spec.epochs.iter().any(|e| e.film.is_some()) {
        write_text(&dir.join("truth/fiducials.csv"), &records.truth_marks)?;
        write_text(&dir.join("truth/scan_transforms.csv"), &records.truth_scans)?;
    }
    if spec.gnss.is_some() {
        write_text(&dir.join("gnss.csv"), &records.gnss)?;
        write_text(&dir.join("truth/gnss_bias.csv"), &records.gnss_bias)?;
    }
    write_points(spec, dir, &records.points_local, rng)?;
    write_cameras_json(
        &dir.join("truth/cameras.json"),
        &Reconstruction {
            crs: spec.crs.clone(),
            cameras: spec
                .epochs
                .iter()
                .map(|e| (e.name.clone(), Camera::Brown(e.camera)))
                .collect(),
            images: records.truth_images,
        },
    )
    .map_err(|e| SynthError::Write(e.to_string()))?;
    write_stable(spec, dir, crs)?;
    write_change(spec, dir)?;
    write_project(spec, dir)?;
    Ok(records.written)
}

/// The scan of one photograph: the photograph rendered through the scan's transform, and the
/// film (its edge, the marks, the data strip) drawn where the scan sees no photograph, with the
/// epoch's supersampling.
fn render_scan(
    scene: &Scene,
    epoch: &EpochSpec,
    film: &FilmSpec,
    scan: &ScanGeometry,
    frame_rays: &FrameRays,
    pose: &Pose,
) -> (RgbImage, (u32, u32)) {
    use rayon::prelude::*;
    let camera = &epoch.camera;
    let size = film.scan_size(camera);
    let scan_camera = ScanCamera {
        camera,
        rays: frame_rays,
        film,
        scan,
        size,
    };
    let rays = RayTable::new(
        &scan_camera,
        size.0 as usize,
        size.1 as usize,
        epoch.supersampling,
    );
    let mut image = render_rays(scene, &rays, pose, epoch.shadows);
    let marks = film.marks_px(camera);
    let strip = film.strip(camera, scan.strip_seed);
    let n = epoch.supersampling.clamp(1, 8) as usize;
    let background = scene.background;
    let width = size.0 as usize;
    image
        .data
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, line)| {
            for (col, out) in line.iter_mut().enumerate() {
                let mut add = Vector3::zeros();
                for s in 0..n * n {
                    let p = Vector2::new(
                        col as f64 + ((s % n) as f64 + 0.5) / n as f64,
                        row as f64 + ((s / n) as f64 + 0.5) / n as f64,
                    );
                    let frame = scan.frame_px(&p);
                    if !film.on_photo(camera, &frame) {
                        let v = film.film_value(camera, &marks, &strip, &frame);
                        add += Vector3::repeat(v) - background;
                    }
                }
                let add = add / (n * n) as f64;
                for c in 0..3 {
                    out[c] += add[c] as f32;
                }
            }
        });
    (image, size)
}

/// `calibration/mark_<epoch>.png`: the mark as a user would cut it from a scan (8-bit grey at
/// the epochs' usual exposure), its centre on the template's centre.
fn write_template(dir: &Path, epoch: &str, film: &FilmSpec) -> Result<(), SynthError> {
    let (size, values) = film.template();
    let pixels: Vec<u8> = values
        .iter()
        .map(|v| (255.0 * 1.3 * v).round().clamp(0.0, 255.0) as u8)
        .collect();
    let path = dir.join(format!("calibration/mark_{epoch}.png"));
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| io_err(parent, e))?;
    }
    let bytes = encode(
        &pixels,
        size as u32,
        size as u32,
        Channels::Grey,
        ImageFormat::Png,
    )
    .map_err(|e| io_err(&path, e))?;
    write_bytes_atomically(&path, &bytes).map_err(|e| SynthError::Write(e.to_string()))
}

/// A standard normal draw truncated at ±3.5: marker measurement noise; a larger error would be a
/// blunder, which scenes do not model.
fn truncated_normal(rng: &mut SeededRng) -> f64 {
    loop {
        let z = rng.normal();
        if z.abs() <= 3.5 {
            return z;
        }
    }
}

/// Whether the scene is consistent: names unique, control on stable ground, regions inside the
/// grid.
fn validate(spec: &SceneSpec) -> Result<(), SynthError> {
    let bad = |m: String| Err(SynthError::InvalidScene(format!("{}: {m}", spec.name)));
    if spec.epochs.is_empty() {
        return bad("no epochs".into());
    }
    let mut names = std::collections::BTreeSet::new();
    for (_, p) in spec.named_points() {
        if !names.insert(p.name.as_str()) {
            return bad(format!("point name {} used twice", p.name));
        }
        if !spec.is_stable(p.at.0, p.at.1) {
            return bad(format!("point {} is not on stable ground", p.name));
        }
    }
    for e in &spec.epochs {
        e.camera
            .validate()
            .map_err(|err| SynthError::InvalidScene(format!("camera of {}: {err}", e.name)))?;
    }
    Ok(())
}

/// The pixel where `p` is seen in an image, when it is in the frame, in front, facing the camera
/// and not hidden.
fn observe(
    scene: &Scene,
    camera: &timesift_core::BrownCamera,
    pose: &Pose,
    x: &Vector3<f64>,
    normal: &Vector3<f64>,
) -> Option<Vector2<f64>> {
    let px = project_world(camera, pose, x).ok()?;
    let margin = 4.0;
    if px.x < margin
        || px.y < margin
        || px.x > camera.width as f64 - margin
        || px.y > camera.height as f64 - margin
    {
        return None;
    }
    // A projection can also come from a point behind the camera with wild distortion: check
    // that the ray through the pixel points at the point.
    let c = pose.center();
    let to_point = (x - c).normalize();
    let ray = camera.unproject(&px).ok()?;
    let ray_world = (pose.rotation.inverse() * ray).normalize();
    if ray_world.dot(&to_point) < 1.0 - 1e-9 {
        return None;
    }
    if normal.dot(&(c - x)).abs() < 0.25 * (c - x).norm() {
        return None; // grazing view: the target would be unmeasurable
    }
    let distance = (x - c).norm();
    scene.sees(&c, x, 1e-6 * distance + 1e-4).then_some(px)
}

/// The EXIF a digital camera writes: its 35 mm equivalent focal length, an integer, so the
/// nominal value is off the true calibration by up to 2 % (as real EXIF focal lengths are).
/// Film scans (TIFF) carry none.
fn camera_tags(camera: &timesift_core::BrownCamera) -> CameraTags {
    let long_side = camera.width.max(camera.height) as f64;
    CameraTags {
        make: "timesift-synth".into(),
        model: format!("{}x{}", camera.width, camera.height),
        focal_length_35mm: (36.0 * camera.f / long_side).round() as u16,
    }
}

fn encode(
    pixels: &[u8],
    width: u32,
    height: u32,
    channels: Channels,
    format: ImageFormat,
) -> Result<Vec<u8>, image::ImageError> {
    use image::ImageEncoder;
    let colour = match channels {
        Channels::Rgb => image::ExtendedColorType::Rgb8,
        Channels::Grey => image::ExtendedColorType::L8,
    };
    let mut out = Cursor::new(Vec::new());
    match format {
        ImageFormat::Jpeg(q) => image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, q)
            .write_image(pixels, width, height, colour)?,
        ImageFormat::Png => image::codecs::png::PngEncoder::new(&mut out)
            .write_image(pixels, width, height, colour)?,
        ImageFormat::Tiff => image::codecs::tiff::TiffEncoder::new(&mut out)
            .write_image(pixels, width, height, colour)?,
    }
    Ok(out.into_inner())
}

/// North-up raster of the grid: pixel centres on the grid nodes.
fn grid_georef(spec: &SceneSpec, crs: Crs) -> (usize, usize, GeoReference) {
    let (x0, y0, cell, nx, ny) = spec.grid;
    let (ox, oy, crs) = match spec.frame {
        Frame::Ground => (spec.origin.x, spec.origin.y, crs),
        Frame::Wall => (0.0, 0.0, Crs::Local),
    };
    (
        nx,
        ny,
        GeoReference {
            transform: GeoTransform {
                origin_x: ox + x0 - 0.5 * cell,
                origin_y: oy + y0 + (ny as f64 - 0.5) * cell,
                pixel_width: cell,
                pixel_height: -cell,
            },
            crs,
            nodata: None,
            pixel_is_point: false,
        },
    )
}

fn grid_position(spec: &SceneSpec, col: usize, row: usize) -> (f64, f64) {
    let (x0, y0, cell, _, ny) = spec.grid;
    (x0 + col as f64 * cell, y0 + (ny - 1 - row) as f64 * cell)
}

fn write_dem(
    spec: &SceneSpec,
    field: &Heightfield,
    epoch: usize,
    crs: Crs,
    path: &Path,
) -> Result<(), SynthError> {
    let offset = match spec.frame {
        Frame::Ground => spec.origin.z,
        Frame::Wall => 0.0,
    };
    write_grid(spec, crs, Some(-32767.0), path, |x, y| {
        spec.surface(field, epoch, x, y).unwrap_or(f64::NAN) + offset
    })
}

/// Writes a float32 GeoTIFF on the scene grid (pixel centres on the grid nodes) of `value` at
/// each node.
fn write_grid(
    spec: &SceneSpec,
    crs: Crs,
    nodata: Option<f64>,
    path: &Path,
    value: impl Fn(f64, f64) -> f64,
) -> Result<(), SynthError> {
    let (nx, ny, mut georef) = grid_georef(spec, crs);
    georef.nodata = nodata;
    let mut data = Vec::with_capacity(nx * ny);
    for row in 0..ny {
        for col in 0..nx {
            let (x, y) = grid_position(spec, col, row);
            data.push(value(x, y) as f32);
        }
    }
    write_f32(
        path,
        &GeoRaster {
            width: nx,
            height: ny,
            bands: 1,
            data,
            georef,
        },
    )
    .map_err(|e| SynthError::Write(e.to_string()))
}

/// The surface mesh in world coordinates, binary little-endian PLY.
fn write_ply(spec: &SceneSpec, field: &Heightfield, path: &Path) -> Result<(), SynthError> {
    let (vertices, triangles) = field.mesh();
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\ncomment timesift synth: true surface\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
         element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        vertices.len(),
        triangles.len()
    )
    .into_bytes();
    for v in &vertices {
        let w = spec.frame.to_local(v.x, v.y, v.z) + spec.origin;
        for c in [w.x, w.y, w.z] {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &triangles {
        bytes.push(3);
        for i in t {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
    }
    write_bytes_atomically(path, &bytes).map_err(|e| SynthError::Write(e.to_string()))
}

fn write_points(
    spec: &SceneSpec,
    dir: &Path,
    points: &[(String, &'static str, Vector3<f64>)],
    rng: &mut SeededRng,
) -> Result<(), SynthError> {
    let mut truth = String::from("name,kind,x,y,z\n");
    let (sh, sv) = spec.survey_sigma;
    let mut gcps = String::from("name,x,y,z,sxy,sz\n");
    let mut checks = String::from("name,x,y,z\n");
    for (name, kind, local) in points {
        let w = local + spec.origin;
        let _ = writeln!(truth, "{name},{kind},{:.6},{:.6},{:.6}", w.x, w.y, w.z);
        let surveyed = w + Vector3::new(sh * rng.normal(), sh * rng.normal(), sv * rng.normal());
        match *kind {
            "gcp" => {
                let _ = writeln!(
                    gcps,
                    "{name},{:.4},{:.4},{:.4},{sh},{sv}",
                    surveyed.x, surveyed.y, surveyed.z
                );
            }
            "checkpoint" => {
                let _ = writeln!(
                    checks,
                    "{name},{:.4},{:.4},{:.4}",
                    surveyed.x, surveyed.y, surveyed.z
                );
            }
            _ => {}
        }
    }
    write_text(&dir.join("truth/points.csv"), &truth)?;
    write_text(&dir.join("gcps.csv"), &gcps)?;
    write_text(&dir.join("checkpoints.csv"), &checks)?;
    if !spec.scale_bars.is_empty() {
        let position = |n: &str| points.iter().find(|p| p.0 == n).map(|p| p.2);
        let mut bars = String::from("a,b,distance,sd\n");
        for bar in &spec.scale_bars {
            let (Some(a), Some(b)) = (position(&bar.a), position(&bar.b)) else {
                return Err(SynthError::InvalidScene(format!(
                    "scale bar {}–{} names an unknown target",
                    bar.a, bar.b
                )));
            };
            let _ = writeln!(bars, "{},{},{:.5},0.0002", bar.a, bar.b, (a - b).norm());
        }
        write_text(&dir.join("scalebars.csv"), &bars)?;
    }
    Ok(())
}

/// Images of the first epoch that must measure a natural stable point (`manual` intersects it
/// there) and of every other epoch (it controls them).
const NATURAL_REFERENCE_IMAGES: usize = 4;
const NATURAL_OTHER_IMAGES: usize = 2;

/// Keeps the natural stable point candidates measured in enough images of every epoch, spreads
/// [`crate::scene::NATURAL_POINTS`] of them over the scene, and writes `stable_points.csv`,
/// their markers (noise from a stream of their own, so the targets' markers and the GNSS are
/// what they would be without them) and `truth/stable_points.csv`. Returns the markers written.
fn write_natural_points(
    spec: &SceneSpec,
    candidates: &[(f64, f64)],
    local: &[Vector3<f64>],
    seen: &[Vec<(String, usize, Vector2<f64>)>],
    markers: &mut String,
    dir: &Path,
) -> Result<usize, SynthError> {
    let usable: Vec<usize> = (0..candidates.len())
        .filter(|&k| {
            (0..spec.epochs.len()).all(|e| {
                let n = seen[k].iter().filter(|s| s.1 == e).count();
                n >= if e == 0 {
                    NATURAL_REFERENCE_IMAGES
                } else {
                    NATURAL_OTHER_IMAGES
                }
            })
        })
        .collect();
    let at: Vec<(f64, f64)> = usable.iter().map(|&k| candidates[k]).collect();
    let chosen = crate::scene::spread_out(spec.grid, &at, crate::scene::NATURAL_POINTS);
    let mut rng = SeededRng::new(spec.seed ^ 0x4E47_5552_414C);
    let mut listed = String::from("name\n");
    let mut truth = String::from("name,x,y,z\n");
    let mut written = 0;
    for (n, &c) in chosen.iter().enumerate() {
        let k = usable[c];
        let name = format!("natural-{}", n + 1);
        let w = local[k] + spec.origin;
        let _ = writeln!(listed, "{name}");
        let _ = writeln!(truth, "{name},{:.6},{:.6},{:.6}", w.x, w.y, w.z);
        for (image, _, px) in &seen[k] {
            let noisy = px
                + Vector2::new(truncated_normal(&mut rng), truncated_normal(&mut rng))
                    * spec.marker_sigma;
            let _ = writeln!(markers, "{image},{name},{:.3},{:.3}", noisy.x, noisy.y);
            written += 1;
        }
    }
    write_text(&dir.join("stable_points.csv"), &listed)?;
    write_text(&dir.join("truth/stable_points.csv"), &truth)?;
    Ok(written)
}

fn ring_wkt(ring: &[[f64; 2]], offset: (f64, f64)) -> String {
    let mut s = String::from("(");
    for (k, p) in ring.iter().chain(ring.first()).enumerate() {
        if k > 0 {
            s.push_str(", ");
        }
        let _ = write!(s, "{:.3} {:.3}", p[0] + offset.0, p[1] + offset.1);
    }
    s.push(')');
    s
}

/// The frame offset of the grid in written files: world for ground scenes, none for walls.
fn grid_offset(spec: &SceneSpec) -> (f64, f64) {
    match spec.frame {
        Frame::Ground => (spec.origin.x, spec.origin.y),
        Frame::Wall => (0.0, 0.0),
    }
}

/// The stable area as one polygon: the grid's extent with every unstable polygon as a hole.
pub fn stable_wkt(spec: &SceneSpec) -> String {
    let (x0, y0, cell, nx, ny) = spec.grid;
    let (x1, y1) = (x0 + (nx - 1) as f64 * cell, y0 + (ny - 1) as f64 * cell);
    let offset = grid_offset(spec);
    let mut s = String::from("POLYGON (");
    s.push_str(&ring_wkt(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]], offset));
    for hole in &spec.unstable {
        s.push_str(", ");
        s.push_str(&ring_wkt(hole, offset));
    }
    s.push(')');
    s
}

fn write_stable(spec: &SceneSpec, dir: &Path, crs: Crs) -> Result<(), SynthError> {
    // Holes must not overlap, or the even–odd rule would flip them back to stable.
    for (i, a) in spec.unstable.iter().enumerate() {
        for b in &spec.unstable[i + 1..] {
            if a.iter().any(|p| ring_contains(b, p[0], p[1]))
                || b.iter().any(|p| ring_contains(a, p[0], p[1]))
            {
                return Err(SynthError::InvalidScene(format!(
                    "{}: unstable polygons overlap",
                    spec.name
                )));
            }
        }
    }
    if spec.frame == Frame::Ground {
        write_text(
            &dir.join("stable.csv"),
            &format!("name,wkt\nstable,\"{}\"\n", stable_wkt(spec)),
        )?;
    }
    write_grid(spec, crs, None, &dir.join("truth/stable.tif"), |x, y| {
        if spec.is_stable(x, y) { 1.0 } else { 0.0 }
    })
}

fn write_change(spec: &SceneSpec, dir: &Path) -> Result<(), SynthError> {
    let offset = grid_offset(spec);
    let regions: Vec<_> = spec
        .regions
        .iter()
        .map(|r| {
            let mut volumes = Vec::new();
            for a in 0..spec.epochs.len() {
                for b in a + 1..spec.epochs.len() {
                    volumes.push(json!({
                        "from": spec.epochs[a].name,
                        "to": spec.epochs[b].name,
                        "volume_m3": spec.true_volume(r, a, b),
                    }));
                }
            }
            json!({
                "name": r.name,
                "description": r.description,
                "polygon_wkt": format!("POLYGON ({})", ring_wkt(&r.polygon, offset)),
                "volumes": volumes,
            })
        })
        .collect();
    let (x0, y0, cell, nx, ny) = spec.grid;
    let frame = match spec.frame {
        Frame::Ground => "ground: DEMs and polygons in world coordinates (E, N), heights H",
        Frame::Wall => {
            "wall: DEMs and polygons in wall coordinates (x = world E − origin E along the wall, \
             y = world H − origin H up the wall), values = world N − origin N out of the wall"
        }
    };
    let doc = json!({
        "scene": spec.name,
        "crs": spec.crs,
        "origin": [spec.origin.x, spec.origin.y, spec.origin.z],
        "frame": frame,
        "grid": { "origin": [x0 + offset.0, y0 + offset.1], "cell": cell, "nx": nx, "ny": ny },
        "epochs": spec.epochs.iter().map(|e| e.name.clone()).collect::<Vec<_>>(),
        "stable_mask": "truth/stable.tif",
        "stable_wkt": stable_wkt(spec),
        "regions": regions,
    });
    let text = serde_json::to_string_pretty(&doc).map_err(|e| SynthError::Write(e.to_string()))?;
    write_text(&dir.join("truth/change.json"), &(text + "\n"))
}

/// Side of an aerial film frame (23 cm × 23 cm), scanned whole.
const FILM_FRAME_MM: f64 = 230.0;

fn write_project(spec: &SceneSpec, dir: &Path) -> Result<(), SynthError> {
    let mut s = format!(
        "# Synthetic scene `{}` written by `cargo xtask synth`; the truth is in truth/.\n\
         crs = \"{}\"\n",
        spec.name, spec.crs
    );
    for e in &spec.epochs {
        let _ = write!(
            s,
            "\n[[epoch]]\nname = \"{}\"\nimages = \"images/{}/*.{}\"\n",
            e.name,
            e.name,
            e.format.extension()
        );
    }
    let _ = write!(
        s,
        "\n[align]\nmethod = \"timesift\"\nreference_epoch = \"{}\"\n",
        spec.epochs[0].name
    );
    // Film scans carry no EXIF, but an aerial film camera comes with a calibration certificate
    // (calibrated focal length in mm) and the scan has a known resolution: what a user of
    // archival photos types into `[[camera]]`.
    for e in spec
        .epochs
        .iter()
        .filter(|e| matches!(e.format, ImageFormat::Tiff) || e.film.is_some())
    {
        let pixel_mm = match &e.film {
            Some(film) => film.pixel_mm,
            None => FILM_FRAME_MM / e.camera.width.max(e.camera.height) as f64,
        };
        let what = match e.film {
            Some(_) => "Calibration certificate of the film camera, and the scan resolution.",
            None => "Calibration of the digital frame camera (its TIFFs carry no EXIF).",
        };
        let _ = write!(
            s,
            "\n# {what}\n[[camera]]\nname = \"{}\"\nfocal_mm = {:.3}\npixel_mm = {:.7}\n",
            e.name,
            e.camera.f * pixel_mm,
            pixel_mm
        );
        if let Some(film) = &e.film {
            let pp = film.principal_point_mm;
            let _ = write!(
                s,
                "principal_point_mm = [{:.4}, {:.4}]\n\
                 fiducial_template = \"calibration/mark_{}.png\"\n[camera.fiducials]\n",
                pp.x, pp.y, e.name
            );
            for (name, mm) in &film.marks {
                let _ = writeln!(s, "\"{name}\" = [{:.4}, {:.4}]", mm.x, mm.y);
            }
        }
    }
    write_text(&dir.join("project.toml"), &s)
}
