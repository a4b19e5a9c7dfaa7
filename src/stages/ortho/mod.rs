//! The `ortho` stage: per epoch, a true orthomosaic of the epoch's images on the project's ortho
//! lattice (`out/grid.json`), sampled from the original images through the frozen orientation
//! at the heights of the epoch's own `dem.tif`: `ortho.tif` (RGBA, alpha 0 where no image sees
//! the ground) and a preview `ortho.png`.
//!
//! Images are read on demand through a small cache, so memory holds the images of the tiles in
//! flight, not the epoch; the mosaic is written a band of rows at a time as it is made, so
//! memory never holds the mosaic either (an ortho over 4 GiB is written as BigTIFF). An epoch's
//! ortho is redone only when its DEM, its orientation or the ortho options change
//! (`work/raster/<epoch>.ortho.json`).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use timesift_core::CameraModel;
use timesift_dense::EpochInput;
use timesift_io::geotiff::{GeoTiffWriter, read_f32};
use timesift_io::tiled_tiff::{Pixels, SampleFormat};
use timesift_raster::{
    Downscaler, Lattice, OrthoMosaic, OrthoOptions, OrthoStats, OrthoView, RgbImage,
    TileRowFigures, ViewImages, ortho_stats,
};

use super::cache::file_stamp;
use super::cache::stage_error;
use super::dem::{
    OrthoRecord, georeference, on_lattice, project_grid_of, raster_report_from_records,
};
use super::{PipelineStage, Stage, dense_inputs};
use crate::film::ImageSource;
use crate::report::{
    GridFile, RasterReport, read_json, read_sealed_json, write_json, write_sealed_json,
};
use crate::{Project, ProjectError};

mod parts;

pub(in crate::stages) use parts::{gains_unit, merge_unit, unit};

/// Version of the mosaicking, part of each ortho's settings.
const ORTHO_ALGORITHM: u32 = 1;

/// Decoded images kept: enough for the candidate views of the tiles two threads work on...
const IMAGE_CACHE: usize = 48;
/// ...within this many bytes (48 decoded 20-megapixel photographs would take 2.9 GB). Images a
/// tile still uses stay alive through the tile's own handles when the cache lets them go.
const IMAGE_CACHE_BYTES: usize = 1536 << 20;

/// The `ortho` stage.
pub(super) struct OrthoStage;

impl PipelineStage for OrthoStage {
    fn stage(&self) -> Stage {
        Stage::Ortho
    }
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)> {
        let layout = project.layout();
        let mut inputs = vec![
            (layout.cameras_json(), Stage::Align),
            (layout.grid_json(), Stage::Dem),
        ];
        inputs.extend(
            project
                .epochs
                .iter()
                .map(|e| (layout.dem(&e.name), Stage::Dem)),
        );
        inputs
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        let layout = project.layout();
        let mut out = vec![layout.raster_report()];
        for e in &project.epochs {
            out.extend([layout.ortho(&e.name), layout.ortho_preview(&e.name)]);
        }
        out
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let report = ortho_stage(project)?;
        Ok(format!("orthomosaics of {} epochs", report.epochs.len()))
    }
}

/// An epoch's images, read on demand, the most recently used kept.
pub(super) struct ImageCache<'a> {
    project: &'a Project,
    source: &'a ImageSource,
    /// Project index of each view's image.
    images: Vec<usize>,
    paths: Vec<PathBuf>,
    /// Width and height of each view's camera, which its image must have.
    sizes: Vec<(u32, u32)>,
    entries: Mutex<VecDeque<(usize, Arc<RgbImage>)>>,
}

impl<'a> ImageCache<'a> {
    /// An empty cache of the images of `views` (project indices `images`).
    fn new(
        project: &'a Project,
        source: &'a ImageSource,
        images: Vec<usize>,
        views: &[OrthoView],
    ) -> ImageCache<'a> {
        ImageCache {
            project,
            source,
            paths: images
                .iter()
                .map(|&i| project.dir.join(&project.images[i].name))
                .collect(),
            images,
            sizes: views
                .iter()
                .map(|v| (v.camera.width(), v.camera.height()))
                .collect(),
            entries: Mutex::new(VecDeque::new()),
        }
    }
}

impl ViewImages for ImageCache<'_> {
    fn image(&self, view: usize) -> Result<Arc<RgbImage>, String> {
        if let Ok(mut entries) = self.entries.lock()
            && let Some(pos) = entries.iter().position(|(v, _)| *v == view)
            && let Some(entry) = entries.remove(pos)
        {
            let image = entry.1.clone();
            entries.push_back(entry);
            return Ok(image);
        }
        let path = self
            .paths
            .get(view)
            .ok_or_else(|| format!("no image for view {view}"))?;
        let image_index = *self
            .images
            .get(view)
            .ok_or_else(|| format!("no image for view {view}"))?;
        let (width, height, data) = match self.source.as_is(self.project, image_index) {
            // A scan in its camera's frame, or an image with a camera mask: black off the
            // photograph and under the mask, which is no-data.
            false => {
                let seen = self
                    .source
                    .read(self.project, image_index, false)
                    .map_err(|e| e.to_string())?;
                let usable = seen.usable.unwrap_or_default();
                let data = seen
                    .image
                    .data
                    .chunks(3)
                    .enumerate()
                    .flat_map(|(k, rgb)| {
                        let on = usable.get(k).copied().unwrap_or(false);
                        rgb.iter().map(move |&v| {
                            if on {
                                (255.0 * v).round().clamp(1.0, 255.0) as u8
                            } else {
                                0
                            }
                        })
                    })
                    .collect();
                (seen.image.width, seen.image.height, data)
            }
            true => timesift_io::image::read_rgb8(path).map_err(|e| e.to_string())?,
        };
        if let Some(&(w, h)) = self.sizes.get(view)
            && (w, h) != (width, height)
        {
            return Err(format!(
                "{}: {width} × {height} pixels, but its camera in out/cameras.json is {w} × {h}",
                path.display()
            ));
        }
        let image = Arc::new(RgbImage {
            width: width as usize,
            height: height as usize,
            data,
        });
        if let Ok(mut entries) = self.entries.lock() {
            entries.push_back((view, image.clone()));
            let mut bytes: usize = entries.iter().map(|(_, image)| image.data.len()).sum();
            while entries.len() > 1 && (entries.len() > IMAGE_CACHE || bytes > IMAGE_CACHE_BYTES) {
                if let Some((_, image)) = entries.pop_front() {
                    bytes -= image.data.len();
                }
            }
        }
        Ok(image)
    }
}

/// Runs the ortho stage; returns (and writes) `out/raster.json`.
pub fn ortho_stage(project: &Project) -> Result<RasterReport, ProjectError> {
    let context = OrthoContext::new(project)?;
    for e in 0..project.epochs.len() {
        ortho_epoch(project, &context, e)?;
    }
    report_unit(project)?;
    Ok(raster_report_from_records(project))
}

/// The stage's last step (`ortho-report`): `out/raster.json` from every epoch's DEM and ortho
/// records. The files it owns.
pub(super) fn report_unit(project: &Project) -> Result<Vec<PathBuf>, ProjectError> {
    let path = project.layout().raster_report();
    write_json(&path, &raster_report_from_records(project))?;
    Ok(vec![path])
}

/// What every epoch's ortho reads: the lattice, the epochs' views, the image source.
pub(super) struct OrthoContext {
    grid: timesift_raster::ProjectGrid,
    crs: timesift_io::coords::Crs,
    inputs: Vec<(Vec<usize>, EpochInput)>,
    source: ImageSource,
}

impl OrthoContext {
    fn new(project: &Project) -> Result<OrthoContext, ProjectError> {
        let layout = project.layout();
        let grid_file = read_json::<GridFile>(&layout.grid_json())?;
        let (grid, crs) = project_grid_of(&grid_file).map_err(|e| ProjectError::Path {
            path: layout.grid_json(),
            message: e,
        })?;
        Ok(OrthoContext {
            grid,
            crs,
            inputs: dense_inputs(project)?,
            source: ImageSource::of(project)?,
        })
    }
}

/// One epoch's mosaic to make: its DEM's heights, its views, its options and what it is made
/// from.
pub(super) struct EpochOrtho {
    e: usize,
    name: String,
    heights: Vec<f32>,
    views: Vec<OrthoView>,
    options: OrthoOptions,
    /// What the ortho is made from (`work/raster/<epoch>.ortho.json`'s `made_from`).
    settings: serde_json::Value,
    up_to_date: bool,
}

impl EpochOrtho {
    fn new(
        project: &Project,
        context: &OrthoContext,
        e: usize,
    ) -> Result<EpochOrtho, ProjectError> {
        let layout = project.layout();
        let (_, input) = &context.inputs[e];
        let name = project.epochs[e].name.clone();
        let dem_path = layout.dem(&name);
        let options = project.config.raster.ortho_options(
            context.grid.ortho_factor,
            project.config.dense.black_is_nodata,
        );
        let settings = ortho_settings(
            &dem_path,
            &options,
            input,
            context.source.fingerprint(project),
        );
        let up_to_date = read_sealed_json::<OrthoRecord>(&layout.raster_settings(&name, "ortho"))
            .is_ok_and(|r| r.made_from == settings)
            && layout.ortho(&name).is_file();
        let (heights, views) = if up_to_date {
            (Vec::new(), Vec::new())
        } else {
            let views = input
                .views
                .iter()
                .map(|v| OrthoView {
                    camera: v.camera.clone(),
                    cam_from_world: v.cam_from_world,
                })
                .collect();
            (dem_heights(&dem_path, &context.grid.dem)?, views)
        };
        Ok(EpochOrtho {
            e,
            name,
            heights,
            views,
            options,
            settings,
            up_to_date,
        })
    }

    fn up_to_date(&self) -> bool {
        if self.up_to_date {
            tracing::info!(epoch = %self.name, "ortho up to date");
        }
        self.up_to_date
    }

    /// A failure of this epoch's mosaic, as the stage reports it.
    fn error(&self, e: impl std::fmt::Display) -> ProjectError {
        stage_error("ortho", format!("epoch \"{}\": {e}", self.name))
    }

    fn mosaic<'a>(&'a self, context: &'a OrthoContext) -> Result<OrthoMosaic<'a>, ProjectError> {
        OrthoMosaic::new(&self.heights, &context.grid.dem, &self.views, &self.options)
            .map_err(|e| self.error(e))
    }

    fn images<'a>(&self, project: &'a Project, context: &'a OrthoContext) -> ImageCache<'a> {
        let (images, _) = &context.inputs[self.e];
        ImageCache::new(project, &context.source, images.clone(), &self.views)
    }
}

/// Epoch `e`'s orthomosaic, made whole, unless what it was made from is unchanged; whether it
/// was made.
fn ortho_epoch(project: &Project, context: &OrthoContext, e: usize) -> Result<bool, ProjectError> {
    let epoch = EpochOrtho::new(project, context, e)?;
    if epoch.up_to_date() {
        return Ok(false);
    }
    let mosaic = epoch.mosaic(context)?;
    let cache = epoch.images(project, context);
    let start = Instant::now();
    let bar = crate::progress::progress_bar(project.progress, "ortho", &epoch.name, 0, "tiles");
    let progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    // The mosaic goes to its GeoTIFF and to the preview a band of rows at a time: memory
    // holds the DEM, a few bands and the images of the tiles in flight, whatever the size
    // of the ortho.
    let gains = mosaic
        .gains(&cache, &progress)
        .map_err(|e| epoch.error(e))?;
    let mut writer = OrthoWriter::create(project, context, &epoch.name)?;
    let figures = mosaic
        .make_rows(
            0..mosaic.tile_rows(),
            &cache,
            &gains,
            &progress,
            &mut |_, rgba| writer.push(rgba),
        )
        .map_err(|e| epoch.error(e))?;
    bar.finish_and_clear();
    writer.finish(project, &epoch, &figures, start.elapsed().as_secs_f64())?;
    Ok(true)
}

/// One epoch's `ortho.tif` and preview, written a band of rows at a time, top to bottom.
pub(super) struct OrthoWriter {
    path: PathBuf,
    tiff: GeoTiffWriter,
    preview: Downscaler,
}

impl OrthoWriter {
    fn create(
        project: &Project,
        context: &OrthoContext,
        name: &str,
    ) -> Result<OrthoWriter, ProjectError> {
        let l = context.grid.ortho();
        let path = project.layout().ortho(name);
        let tiff = GeoTiffWriter::create(
            &path,
            l.width(),
            l.height(),
            SampleFormat::U8 { bands: 4 },
            &georeference(&l, context.crs, None),
        )?;
        Ok(OrthoWriter {
            path,
            tiff,
            preview: Downscaler::new(4, l.width(), l.height(), 1024),
        })
    }

    fn push(&mut self, rgba: &[u8]) -> Result<(), String> {
        self.preview.push_rows(rgba);
        self.tiff
            .push_rows(Pixels::U8 {
                data: rgba,
                bands: 4,
            })
            .map_err(|e| e.to_string())
    }

    /// The GeoTIFF, its style, the preview and the epoch's record, from the mosaic's figures
    /// (every tile row's, top to bottom).
    fn finish(
        self,
        project: &Project,
        epoch: &EpochOrtho,
        figures: &[TileRowFigures],
        seconds: f64,
    ) -> Result<(), ProjectError> {
        let layout = project.layout();
        self.tiff.finish()?;
        timesift_io::qgis::write_qml(&self.path, &super::product_styles::ortho())?;
        let (w, h, small) = self.preview.finish();
        timesift_io::image::write_png(
            &layout.ortho_preview(&epoch.name),
            w as u32,
            h as u32,
            4,
            &small,
        )?;
        let stats = ortho_stats(figures);
        let with_height = epoch.heights.iter().filter(|h| h.is_finite()).count();
        let factor2 = (epoch.options.factor * epoch.options.factor) as f64;
        let record = ortho_record(
            epoch.settings.clone(),
            &stats,
            with_height as f64 * factor2,
            seconds,
        );
        tracing::info!(
            epoch = %epoch.name,
            painted = record.ortho_painted_fraction,
            seam_jump = stats.seam_jump,
            seconds,
            "ortho"
        );
        write_sealed_json(&layout.raster_settings(&epoch.name, "ortho"), &record)
    }
}

/// An epoch's ortho figures for the raster report: the share of cells with a height that were
/// painted (`cells` the ortho cells over DEM cells with a height), the seams' jumps, the time.
fn ortho_record(
    made_from: serde_json::Value,
    stats: &OrthoStats,
    cells: f64,
    seconds: f64,
) -> OrthoRecord {
    OrthoRecord {
        made_from,
        ortho_painted_fraction: stats.painted_cells as f64 / cells.max(1.0),
        seam_jump: stats.seam_jump,
        interior_jump: stats.interior_jump,
        ortho_seconds: seconds,
    }
}

/// What an epoch's ortho is made from: the DEM file, the options, every view's camera and pose,
/// the images.
fn ortho_settings(
    dem_path: &Path,
    options: &OrthoOptions,
    input: &EpochInput,
    images: String,
) -> serde_json::Value {
    let poses: Vec<String> = input
        .views
        .iter()
        .map(|v| format!("{:?}{:?}", v.camera, v.cam_from_world))
        .collect();
    serde_json::json!({
        "algorithm": ORTHO_ALGORITHM,
        "dem": file_stamp(dem_path),
        "options": format!("{options:?}"),
        "views": poses,
        "images": images,
    })
}

/// The heights of an epoch's DEM (NaN where it has none), which must lie on the project's DEM
/// lattice.
fn dem_heights(dem_path: &Path, lattice: &Lattice) -> Result<Vec<f32>, ProjectError> {
    let dem = read_f32(dem_path)?;
    if !on_lattice(&dem.georef, dem.width, dem.height, lattice) {
        return Err(ProjectError::Path {
            path: dem_path.to_path_buf(),
            message: "not on the lattice of out/grid.json (run the dem stage)".into(),
        });
    }
    let nodata = dem.georef.nodata.map(|v| v as f32);
    Ok(dem
        .data
        .iter()
        .map(|h| {
            if Some(*h) == nodata || !h.is_finite() {
                f32::NAN
            } else {
                *h
            }
        })
        .collect())
}
