//! The `dense` stage: per epoch, multi-view stereo on the frozen orientation of `out/cameras.json`
//! with the sparse points of `out/colmap/`, into `out/epochs/<epoch>/dense.laz`.
//!
//! Work files (`work/dense/<epoch>/`): the depth, normal and cost maps of every image after every
//! PatchMatch pass (`pass<k>/<n>.exr`), the filtered maps (`filtered/<n>.exr`), and
//! `settings.json`, which records what the maps depend on — the `[dense]` options that change
//! them and a fingerprint of the epoch's cameras and poses. A run resumes image by image: only
//! missing maps are computed, and since every result is deterministic, recomputing one gives
//! the same bits. Options that only change filtering and fusion (`min_views`, `min_images`,
//! `fill_edges`, `max_cost`) keep the maps and redo the cloud.
//!
//! Memory: one reference image with its sources (decoded and resampled, in a small cache) and
//! their maps at a time.

mod input;
mod maps;
mod units;

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::Vector3;
use timesift_core::{Camera, CameraModel};
use timesift_dense::{
    DenseError, DenseOptions, DepthMap, EpochInput, EpochPlan, FusionView, ImageView, Pass,
    PassInput, SparsePoint, UndistortMap, View, WorkingImage, filter_depth_map, fuse, plan_epoch,
    plan_schedule, run_pass,
};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_io::colmap::{ColmapModel, read_colmap_text};
use timesift_io::coords::Crs;
use timesift_io::pointcloud::{
    AttributeValues, ExtraAttribute, LasWriteOptions, PointCloud, write_las,
};

use super::cache::stage_error;
use super::{PipelineStage, Stage};
use crate::film::ImageSource;
use crate::layout::Layout;
use crate::report::{DensePhaseSeconds, DenseReport, EpochDense, read_json, write_json};
use crate::{Project, ProjectError};
pub use input::{dense_input, dense_inputs};

/// A decoded image as the dense crate borrows it (its pixels, not a copy).
pub fn dense_view(decoded: &timesift_io::image::ImageF32) -> ImageView<'_> {
    ImageView {
        width: decoded.width as usize,
        height: decoded.height as usize,
        channels: decoded.channels as usize,
        data: &decoded.data,
    }
}
use input::{epoch_input, match_orientation, orientation_fingerprint};
use maps::{MapCache, read_map, write_map};
pub(crate) use units::{fuse_unit, pass_unit, prepare, report_unit};

/// Version of the depth-map algorithm, part of the maps' settings: a change that alters the maps
/// makes a resumed run redo them.
const DENSE_ALGORITHM: u32 = 10;

/// Version of filtering and fusion, part of the cloud's settings.
const FUSION_ALGORITHM: u32 = 7;

/// The `dense` stage.
pub(super) struct DenseStage;

impl PipelineStage for DenseStage {
    fn stage(&self) -> Stage {
        Stage::Dense
    }
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)> {
        let layout = project.layout();
        vec![
            (layout.cameras_json(), Stage::Align),
            (layout.colmap_dir().join("images.txt"), Stage::Align),
            (layout.colmap_dir().join("points3D.txt"), Stage::Align),
        ]
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        let layout = project.layout();
        project
            .epochs
            .iter()
            .map(|e| layout.dense_cloud(&e.name))
            .chain(std::iter::once(layout.dense_report()))
            .collect()
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let report = dense_stage(project)?;
        let points: usize = report.epochs.values().map(|e| e.points).sum();
        Ok(format!(
            "dense clouds of {} epochs, {points} points",
            report.epochs.len()
        ))
    }
}

fn dense_error(epoch: &str, e: DenseError) -> ProjectError {
    stage_error("dense", format!("epoch \"{epoch}\": {e}"))
}

/// What every unit of the dense stage reads: the frozen orientation and the sparse model.
struct Oriented {
    cameras: Reconstruction,
    model: ColmapModel,
    crs: Crs,
    /// The orientation's camera of each project image.
    oriented: Vec<Option<usize>>,
}

impl Oriented {
    fn read(project: &Project) -> Result<Oriented, ProjectError> {
        let layout = project.layout();
        let cameras = read_cameras_json(&layout.cameras_json())?;
        let model = read_colmap_text(&layout.colmap_dir())?;
        let crs: Crs = cameras
            .crs
            .parse()
            .map_err(|e: String| ProjectError::Path {
                path: layout.cameras_json(),
                message: format!("crs: {e}"),
            })?;
        let oriented = match_orientation(project, &cameras)?;
        Ok(Oriented {
            cameras,
            model,
            crs,
            oriented,
        })
    }
}

/// Runs the dense stage on every epoch; returns (and writes) `out/dense.json`.
pub fn dense_stage(project: &Project) -> Result<DenseReport, ProjectError> {
    let layout = project.layout();
    let oriented = Oriented::read(project)?;
    let mut report = if layout.dense_report().is_file() {
        read_json::<DenseReport>(&layout.dense_report()).unwrap_or_default()
    } else {
        DenseReport::default()
    };
    report
        .epochs
        .retain(|name, _| project.epochs.iter().any(|e| &e.name == name));
    for (e, epoch) in project.epochs.iter().enumerate() {
        let summary = dense_epoch(project, e, &oriented)?;
        tracing::info!(
            epoch = %epoch.name,
            points = summary.points,
            seconds = summary.seconds,
            "dense cloud"
        );
        report.epochs.insert(epoch.name.clone(), summary);
        write_json(&layout.dense_report(), &report)?;
    }
    Ok(report)
}

/// One epoch's inputs to dense matching: its images, plan, schedule and the settings its maps
/// are made with.
struct EpochWork {
    name: String,
    images: Vec<usize>,
    input: EpochInput,
    plan: EpochPlan,
    passes: Vec<Pass>,
    options: DenseOptions,
    source: ImageSource,
    map_settings: serde_json::Value,
    dir: PathBuf,
}

impl EpochWork {
    fn new(project: &Project, epoch: usize, o: &Oriented) -> Result<EpochWork, ProjectError> {
        let name = project.epochs[epoch].name.clone();
        let options = project.config.dense.options(project.image_kind(epoch));
        let (images, input) = epoch_input(project, epoch, &o.cameras, &o.model, &o.oriented)?;
        check_images_exist(project, &name, &images)?;
        let plan = plan_epoch(&input, &options.plan).map_err(|e| dense_error(&name, e))?;
        let passes = plan_schedule(&plan, &options.patchmatch);
        let source = ImageSource::of(project)?;
        // Scans in their frames and camera masks are part of what the maps are made from.
        let fingerprint = orientation_fingerprint(&input) + &source.fingerprint(project);
        let map_settings = map_settings(&options, &fingerprint, &images);
        let dir = project.layout().dense_work_dir(&name);
        Ok(EpochWork {
            name,
            images,
            input,
            plan,
            passes,
            options,
            source,
            map_settings,
            dir,
        })
    }

    /// A cache of the epoch's decoded working images, as large as a reference and its sources
    /// twice over.
    fn image_cache<'a>(&'a self, project: &'a Project) -> ImageCache<'a> {
        ImageCache {
            project,
            source: &self.source,
            images: &self.images,
            maps: BTreeMap::new(),
            views: &self.input.views,
            plan: &self.plan,
            black_is_nodata: self.options.black_is_nodata,
            // A reference and its sources are matched together; filtering and fusion read maps,
            // and only the reference's image for its colours.
            capacity: 2
                * (self
                    .plan
                    .views
                    .iter()
                    .map(|v| v.sources.len())
                    .max()
                    .unwrap_or(0)
                    + 1),
            entries: VecDeque::new(),
            seconds: 0.0,
        }
    }
}

/// What the depth maps depend on.
fn map_settings(options: &DenseOptions, fingerprint: &str, images: &[usize]) -> serde_json::Value {
    let pm = &options.patchmatch;
    serde_json::json!({
        "algorithm": DENSE_ALGORITHM,
        "level": options.plan.level,
        "refine": options.plan.refine,
        "refine_min_cost": pm.refine.min_cost,
        "refine_min_bend": pm.refine.min_bend,
        "refine_grow": pm.refine.grow,
        "max_sources": options.plan.max_sources,
        "window_radius": pm.window_radius,
        "window_step": pm.window_step,
        "sigma_color": pm.sigma_color,
        "iterations": pm.photometric_iterations,
        "geometric_iterations": pm.geometric_iterations,
        "refine_iterations": pm.refine_iterations,
        "black_is_nodata": options.black_is_nodata,
        "orientation": fingerprint,
        "images": images,
    })
}

/// What the cloud depends on besides the maps.
fn cloud_settings(options: &DenseOptions, maps: &serde_json::Value) -> serde_json::Value {
    serde_json::json!({
        "algorithm": FUSION_ALGORITHM,
        "maps": maps,
        "min_views": options.filter.min_views,
        "max_cost": options.filter.max_cost,
        "min_images": options.fusion.min_images,
        "fill_edges": options.fusion.fill_edges,
    })
}

fn read_settings(path: &Path) -> Option<serde_json::Value> {
    crate::report::read_sealed_json(path).ok()
}

fn write_settings(path: &Path, value: &serde_json::Value) -> Result<(), ProjectError> {
    crate::report::write_sealed_json(path, value)
}

/// Decoded and resampled images of an epoch, the most recently used kept.
struct ImageCache<'a> {
    project: &'a Project,
    source: &'a ImageSource,
    images: &'a [usize],
    maps: BTreeMap<String, UndistortMap>,
    views: &'a [View],
    plan: &'a EpochPlan,
    black_is_nodata: bool,
    capacity: usize,
    entries: VecDeque<(usize, Arc<WorkingImage>)>,
    /// Wall seconds spent decoding and undistorting.
    seconds: f64,
}

impl ImageCache<'_> {
    fn get(&mut self, view: usize) -> Result<Arc<WorkingImage>, ProjectError> {
        let found = self.entries.iter().position(|(v, _)| *v == view);
        if let Some(entry) = found.and_then(|pos| self.entries.remove(pos)) {
            let image = entry.1.clone();
            self.entries.push_back(entry);
            return Ok(image);
        }
        let start = Instant::now();
        let image_index = self.images[view];
        // A scan is seen in its camera's frame, its film mask kept out of matching.
        let (decoded, mask) = self
            .source
            .read(self.project, image_index, false)?
            .into_dense_parts();
        let camera = &self.views[view].camera;
        let key = camera_key(camera);
        let map = self.maps.entry(key).or_insert_with(|| {
            UndistortMap::new(camera, self.plan.views[view].camera, self.plan.level)
        });
        let working = map
            .apply(&dense_view(&decoded), mask.as_ref(), self.black_is_nodata)
            .map_err(|e| {
                stage_error(
                    "dense",
                    format!("{}: {e}", self.project.images[image_index].name),
                )
            })?;
        let working = Arc::new(working);
        self.seconds += start.elapsed().as_secs_f64();
        if self.entries.len() >= self.capacity {
            self.entries.pop_front();
        }
        self.entries.push_back((view, working.clone()));
        Ok(working)
    }
}

/// A key telling camera models apart (every parameter's bits).
fn camera_key(camera: &Camera) -> String {
    let mut p = vec![0.0; camera.num_params()];
    camera.params(&mut p);
    let mut key = format!(
        "{}:{}x{}",
        camera.model_name(),
        camera.width(),
        camera.height()
    );
    for v in p {
        key.push_str(&format!(":{:x}", v.to_bits()));
    }
    key
}

/// One epoch's dense cloud: the maps still missing computed, filtered and fused, the cloud and
/// the epoch's summary written; nothing redone when the cloud is up to date.
fn dense_epoch(project: &Project, epoch: usize, o: &Oriented) -> Result<EpochDense, ProjectError> {
    let start = Instant::now();
    let layout: Layout = project.layout();
    let crs = o.crs;
    let work = EpochWork::new(project, epoch, o)?;
    let (name, images, plan, passes, options) = (
        work.name.as_str(),
        &work.images,
        &work.plan,
        &work.passes,
        &work.options,
    );
    start_over_if_changed(&work.dir, &work.map_settings, name)?;
    let cloud_path = layout.dense_cloud(name);
    let cloud_record = work.dir.join("cloud.json");
    let summary_path = layout.dense_summary(name);
    let last = passes.len() - 1;
    let final_maps_present =
        (0..images.len()).all(|v| layout.depth_map_file(name, last, images[v]).is_file());
    let wanted = cloud_settings(options, &work.map_settings);
    if cloud_path.is_file()
        && final_maps_present
        && read_settings(&cloud_record).as_ref() == Some(&wanted)
        && let Ok(previous) = crate::report::read_sealed_json::<EpochDense>(&summary_path)
    {
        return Ok(EpochDense {
            depth_maps_computed: 0,
            seconds: start.elapsed().as_secs_f64(),
            phase_seconds: DensePhaseSeconds::default(),
            ..previous
        });
    }
    let mut cache = work.image_cache(project);
    let mut phases = DensePhaseSeconds::default();
    let map_file = |pass: usize, view: usize| layout.depth_map_file(name, pass, images[view]);
    let mut maps = MapCache::new(MAP_CACHE_BYTES);
    // Fusion needs only the last pass: where every view has it (a cluster's pass steps made
    // them, or only the fusion options changed) the earlier passes are not read again.
    // Filtering, then fusion; a final map there but damaged (its checksum) has the passes
    // make it again, reading the earlier passes' maps where they read back as written.
    let filtered_file = |view: usize| layout.filtered_map_file(name, images[view]);
    let mut computed = 0;
    let mut maps_made = !final_maps_present;
    let (with_depth, upsampled) = loop {
        if maps_made {
            computed = compute_maps(
                plan,
                passes,
                &mut cache,
                &map_file,
                name,
                options,
                &mut maps,
                &mut phases,
            )?;
        }
        let filtered = filter_maps(
            plan,
            last,
            &|view| map_file(last, view),
            &filtered_file,
            name,
            options,
            &mut maps,
            &mut phases,
        );
        match filtered {
            Err(FilterError::Unreadable(path)) if !maps_made => {
                tracing::info!(
                    epoch = name,
                    "{}: unreadable: depth maps made again where unreadable",
                    path.display()
                );
                maps_made = true;
            }
            other => break other?,
        }
    };
    drop(maps);
    let fusion_start = Instant::now();
    let images_before = cache.seconds;
    let cloud = fuse_filtered(plan, &mut cache, &filtered_file, name, options)?;
    // Fusion reads the filtered maps and the images' colours: counted there, not here.
    phases.fusion = fusion_start.elapsed().as_secs_f64() - (cache.seconds - images_before);
    let cloud_start = Instant::now();
    write_cloud(&cloud_path, &cloud, crs)?;
    phases.cloud_file = cloud_start.elapsed().as_secs_f64();
    phases.images = cache.seconds;
    write_settings(&cloud_record, &wanted)?;
    let mean_images = mean_images_per_point(&cloud);
    let summary = EpochDense {
        images: images.len(),
        images_with_sources: plan.views.iter().filter(|v| !v.sources.is_empty()).count(),
        level: options.plan.level,
        passes: passes.len(),
        refined_share: (plan.refined_scales > 0 && with_depth > 0)
            .then(|| (with_depth - upsampled) as f64 / with_depth as f64),
        depth_maps_computed: computed,
        points: cloud.len(),
        mean_images_per_point: mean_images,
        seconds: start.elapsed().as_secs_f64(),
        phase_seconds: phases,
    };
    crate::report::write_sealed_json(&summary_path, &summary)?;
    Ok(summary)
}

/// The epoch's filtered maps fused into its cloud, each view's colours from its image.
fn fuse_filtered(
    plan: &EpochPlan,
    cache: &mut ImageCache<'_>,
    filtered_file: &dyn Fn(usize) -> PathBuf,
    name: &str,
    options: &DenseOptions,
) -> Result<timesift_dense::FusedCloud, ProjectError> {
    fuse(plan, &options.fusion, &mut |view: usize| {
        let map = read_map(&filtered_file(view)).ok_or_else(|| {
            stage_error(
                "dense",
                format!("{}: unreadable depth map", filtered_file(view).display()),
            )
        })?;
        let image = cache.get(view)?;
        Ok::<_, FusionError>(FusionView::new(map, &image))
    })
    .map_err(|e| match e {
        FusionError::Project(p) => p,
        FusionError::Dense(d) => dense_error(name, d),
    })
}

/// The mean number of images a point of `cloud` was fused from (0 for an empty cloud).
fn mean_images_per_point(cloud: &timesift_dense::FusedCloud) -> f64 {
    if cloud.is_empty() {
        0.0
    } else {
        cloud.images.iter().map(|&n| n as f64).sum::<f64>() / cloud.len() as f64
    }
}

/// Errors inside fusion's loader.
enum FusionError {
    Project(ProjectError),
    Dense(DenseError),
}

impl From<DenseError> for FusionError {
    fn from(e: DenseError) -> Self {
        FusionError::Dense(e)
    }
}

impl From<ProjectError> for FusionError {
    fn from(e: ProjectError) -> Self {
        FusionError::Project(e)
    }
}

/// Every image of the epoch is where the project says.
fn check_images_exist(project: &Project, name: &str, images: &[usize]) -> Result<(), ProjectError> {
    for &i in images {
        let path = project.dir.join(&project.images[i].name);
        if !path.is_file() {
            return Err(ProjectError::Path {
                path,
                message: format!("image of epoch \"{name}\" is missing"),
            });
        }
    }
    Ok(())
}

/// Empties the epoch's work folder when the maps' settings (or the orientation) recorded there
/// are not `maps`, and records `maps`.
fn start_over_if_changed(
    work: &Path,
    maps: &serde_json::Value,
    name: &str,
) -> Result<(), ProjectError> {
    let settings_path = Layout::settings_file(work);
    if read_settings(&settings_path).as_ref() != Some(maps) {
        if work.exists() {
            std::fs::remove_dir_all(work).map_err(|e| timesift_io::IoError::io(work, e))?;
            tracing::info!(
                epoch = name,
                "dense settings or orientation changed: maps redone"
            );
        }
        write_settings(&settings_path, maps)?;
    }
    Ok(())
}

/// Bytes of depth maps kept in memory between passes: 384 MiB, all the maps of a pass of 50
/// views of 0.5 MP, or a geometric pass's sources of 4 MP working images.
const MAP_CACHE_BYTES: usize = 384 << 20;

/// Every pass's depth map of every view that is not on disk yet, pass after pass; how many
/// were computed.
#[allow(clippy::too_many_arguments)]
fn compute_maps(
    plan: &EpochPlan,
    passes: &[Pass],
    cache: &mut ImageCache<'_>,
    map_file: &dyn Fn(usize, usize) -> PathBuf,
    name: &str,
    options: &DenseOptions,
    maps: &mut MapCache,
    phases: &mut DensePhaseSeconds,
) -> Result<usize, ProjectError> {
    let views = plan.views.len();
    let bar = crate::progress::progress_bar(
        cache.project.progress,
        "dense",
        name,
        (passes.len() * views) as u64,
        "depth maps",
    );
    let mut computed = 0;
    for (k, pass) in passes.iter().enumerate() {
        for view in 0..views {
            let files = Instant::now();
            let on_disk = read_map(&map_file(k, view));
            phases.map_files += files.elapsed().as_secs_f64();
            if let Some(map) = on_disk {
                maps.put(k, view, Arc::new(map));
                bar.inc(1);
                continue;
            }
            let map = compute_map(plan, cache, maps, map_file, view, k, pass, options, phases)?;
            let files = Instant::now();
            write_map(&map_file(k, view), &map)?;
            maps.put(k, view, Arc::new(map));
            phases.map_files += files.elapsed().as_secs_f64();
            computed += 1;
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    Ok(computed)
}

/// Each view's final map filtered against its neighbours' and written; the pixels with a
/// depth and those of them still on an upsampled plane, over the epoch.
#[allow(clippy::too_many_arguments)]
fn filter_maps(
    plan: &EpochPlan,
    last: usize,
    final_file: &dyn Fn(usize) -> PathBuf,
    filtered_file: &dyn Fn(usize) -> PathBuf,
    name: &str,
    options: &DenseOptions,
    maps: &mut MapCache,
    phases: &mut DensePhaseSeconds,
) -> Result<(usize, usize), FilterError> {
    let mut final_map = |view: usize| {
        maps.get_or_read(last, view, &final_file(view))
            .ok_or_else(|| FilterError::Unreadable(final_file(view)))
    };
    let (mut with_depth, mut upsampled) = (0usize, 0usize);
    for (view, vp) in plan.views.iter().enumerate() {
        let files = Instant::now();
        let own = final_map(view)?;
        with_depth += own.valid_count();
        upsampled += own.upsampled.iter().filter(|&&u| u).count();
        let neighbours = vp
            .neighbours
            .iter()
            .map(|&s| final_map(s))
            .collect::<Result<Vec<_>, _>>()?;
        phases.map_files += files.elapsed().as_secs_f64();
        let refs: Vec<Option<&DepthMap>> = neighbours.iter().map(|m| Some(m.as_ref())).collect();
        let filtering = Instant::now();
        let filtered = filter_depth_map(plan, view, &own, &refs, &options.filter)
            .map_err(|e| dense_error(name, e))?;
        phases.filter += filtering.elapsed().as_secs_f64();
        let files = Instant::now();
        write_map(&filtered_file(view), &filtered)?;
        phases.map_files += files.elapsed().as_secs_f64();
    }
    Ok((with_depth, upsampled))
}

/// Why the final maps could not be filtered.
enum FilterError {
    /// A final map is missing or does not read back as written.
    Unreadable(PathBuf),
    /// Anything else (a file that cannot be written, a failed filter).
    Other(ProjectError),
}

impl From<ProjectError> for FilterError {
    fn from(e: ProjectError) -> Self {
        FilterError::Other(e)
    }
}

impl From<FilterError> for ProjectError {
    fn from(e: FilterError) -> Self {
        match e {
            FilterError::Unreadable(path) => {
                stage_error("dense", format!("{}: unreadable depth map", path.display()))
            }
            FilterError::Other(e) => e,
        }
    }
}

/// One view's map of pass `k`, reading the maps of pass `k − 1` it needs.
#[allow(clippy::too_many_arguments)]
fn compute_map(
    plan: &EpochPlan,
    cache: &mut ImageCache<'_>,
    maps: &mut MapCache,
    map_file: &dyn Fn(usize, usize) -> PathBuf,
    view: usize,
    k: usize,
    pass: &Pass,
    options: &DenseOptions,
    phases: &mut DensePhaseSeconds,
) -> Result<DepthMap, ProjectError> {
    let vp = &plan.views[view];
    let reference = cache.get(view)?;
    let sources = vp
        .sources
        .iter()
        .map(|s| cache.get(s.view))
        .collect::<Result<Vec<_>, _>>()?;
    let mut previous_map = |v: usize| -> Result<Option<Arc<DepthMap>>, ProjectError> {
        if k == 0 {
            return Ok(None);
        }
        let path = map_file(k - 1, v);
        let map = maps.get_or_read(k - 1, v, &path).ok_or_else(|| {
            stage_error("dense", format!("{}: unreadable depth map", path.display()))
        })?;
        Ok(Some(map))
    };
    let files = Instant::now();
    let previous = previous_map(view)?;
    let geometric = pass.kind == timesift_dense::PassKind::Geometric;
    let source_maps: Vec<Option<Arc<DepthMap>>> = if geometric {
        vp.sources
            .iter()
            .map(|s| previous_map(s.view))
            .collect::<Result<_, _>>()?
    } else {
        Vec::new()
    };
    phases.map_files += files.elapsed().as_secs_f64();
    let source_refs: Vec<&WorkingImage> = sources.iter().map(|s| s.as_ref()).collect();
    let map_refs: Vec<Option<&DepthMap>> = source_maps.iter().map(|m| m.as_deref()).collect();
    let input = PassInput {
        reference: &reference,
        sources: &source_refs,
        previous: previous.as_deref(),
        source_maps: &map_refs,
    };
    let name = cache.project.images[cache.images[view]].name.clone();
    let matching = Instant::now();
    let map = run_pass(plan, view, k, pass, &input, &options.patchmatch)
        .map_err(|e| stage_error("dense", format!("{name}: {e}")))?;
    let seconds = matching.elapsed().as_secs_f64();
    use timesift_dense::PassKind;
    *match pass.kind {
        PassKind::Photometric => &mut phases.photometric,
        PassKind::Hierarchy => &mut phases.hierarchy,
        PassKind::Geometric => &mut phases.geometric,
        PassKind::Refine => &mut phases.refine,
    } += seconds;
    Ok(map)
}

/// Writes the fused cloud as LAS 1.4/LAZ: RGB; the normal, the largest reprojection error of
/// its pixels (working-image pixels) and the number of images as extra attributes; the CRS in
/// the header.
fn write_cloud(
    path: &Path,
    cloud: &timesift_dense::FusedCloud,
    crs: Crs,
) -> Result<(), ProjectError> {
    let normal = |k: usize| AttributeValues::F32(cloud.normals.iter().map(|n| n[k]).collect());
    let las = PointCloud {
        positions: cloud
            .positions
            .iter()
            .map(|p: &Vector3<f64>| [p.x, p.y, p.z])
            .collect(),
        colors: Some(
            cloud
                .colors
                .iter()
                .map(|c| c.map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16))
                .collect(),
        ),
        attributes: vec![
            ExtraAttribute {
                name: "normal_x".into(),
                values: normal(0),
            },
            ExtraAttribute {
                name: "normal_y".into(),
                values: normal(1),
            },
            ExtraAttribute {
                name: "normal_z".into(),
                values: normal(2),
            },
            ExtraAttribute {
                name: "reprojection_px".into(),
                values: AttributeValues::F32(cloud.reprojection_px.clone()),
            },
            ExtraAttribute {
                name: "images".into(),
                values: AttributeValues::U8(
                    cloud.images.iter().map(|&n| n.min(255) as u8).collect(),
                ),
            },
        ],
        crs,
    };
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| timesift_io::IoError::io(parent, e))?;
    }
    write_las(path, &las, &LasWriteOptions::default())?;
    Ok(())
}
