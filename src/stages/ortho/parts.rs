//! The orthomosaics made in parts (the cluster's `ortho-gains`, `ortho` and `ortho-merge`
//! steps): each epoch's exposure gains once, its rows of tiles shared out among units that
//! write them as parts under `work/raster/`, and one merge per epoch that writes the
//! `ortho.tif` a whole mosaic gives, bit for bit (`OrthoWriter` for both).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use timesift_raster::TileRowFigures;

use super::{EpochOrtho, OrthoContext, OrthoWriter};
use crate::report::{read_sealed_json, write_sealed_json};
use crate::stages::Part;
use crate::stages::cache::stage_error;
use crate::{Project, ProjectError};

/// A unit of the `ortho-gains` step: the exposure gains of the orthomosaics of the epochs of
/// `part` (a fit over every tile's overlaps, which every part of a mosaic needs), for those
/// whose ortho is not up to date. The files it owns.
pub(in crate::stages) fn gains_unit(
    project: &Project,
    part: Part,
) -> Result<Vec<PathBuf>, ProjectError> {
    let context = OrthoContext::new(project)?;
    let mut owned = Vec::new();
    for e in part.range(project.epochs.len()) {
        let epoch = EpochOrtho::new(project, &context, e)?;
        if epoch.up_to_date() {
            continue;
        }
        let mosaic = epoch.mosaic(&context)?;
        let cache = epoch.images(project, &context);
        let start = Instant::now();
        let gains = mosaic
            .gains(&cache, &|_, _| {})
            .map_err(|e| epoch.error(e))?;
        let path = project.layout().raster_settings(&epoch.name, "ortho-gains");
        write_sealed_json(
            &path,
            &GainsRecord {
                made_from: epoch.settings.clone(),
                gains,
                seconds: start.elapsed().as_secs_f64(),
            },
        )?;
        owned.push(path);
    }
    Ok(owned)
}

/// A unit of the `ortho` step: its share of every epoch's rows of tiles (the list of (epoch,
/// tile row), epoch by epoch), made with the epoch's gains and written as one part per epoch it
/// touches (`work/raster/<epoch>.ortho-part-<i>-of-<n>.png`, with its figures in the `.json`
/// beside it), for the epochs whose ortho is not up to date. The files it owns.
pub(in crate::stages) fn unit(project: &Project, part: Part) -> Result<Vec<PathBuf>, ProjectError> {
    let context = OrthoContext::new(project)?;
    let tile_rows = tile_rows_of(project, &context);
    let epochs = project.epochs.len();
    let share = part.range(epochs * tile_rows);
    let mut owned = Vec::new();
    for e in 0..epochs {
        // The share's rows within epoch e's, counted from its first.
        let (first, past) = (e * tile_rows, (e + 1) * tile_rows);
        let rows = share.start.clamp(first, past) - first..share.end.clamp(first, past) - first;
        if rows.is_empty() {
            continue;
        }
        let epoch = EpochOrtho::new(project, &context, e)?;
        if epoch.up_to_date() {
            continue;
        }
        owned.extend(write_part(project, &context, &epoch, part, rows)?);
    }
    Ok(owned)
}

/// A unit of the `ortho-merge` step: the orthomosaics of the epochs of `part` from their parts
/// (every row of tiles once, made with the current settings and gains), written as the local
/// executor writes them, bit for bit. The files it owns.
pub(in crate::stages) fn merge_unit(
    project: &Project,
    part: Part,
) -> Result<Vec<PathBuf>, ProjectError> {
    let context = OrthoContext::new(project)?;
    let layout = project.layout();
    let mut owned = Vec::new();
    for e in part.range(project.epochs.len()) {
        let epoch = EpochOrtho::new(project, &context, e)?;
        if !epoch.up_to_date() {
            merge_parts(project, &context, &epoch)?;
        }
        let name = &project.epochs[e].name;
        owned.extend([
            layout.ortho(name),
            layout.ortho_preview(name),
            layout.raster_settings(name, "ortho"),
        ]);
    }
    Ok(owned)
}

/// Rows of tiles of every epoch's mosaic (they share one lattice and the project's options).
fn tile_rows_of(project: &Project, context: &OrthoContext) -> usize {
    let options = project.config.raster.ortho_options(
        context.grid.ortho_factor,
        project.config.dense.black_is_nodata,
    );
    context.grid.dem.height().div_ceil(options.tile.max(1))
}

/// `work/raster/<epoch>.ortho-gains.json`: an epoch's exposure gains, and what its ortho is
/// made from.
#[derive(serde::Serialize, serde::Deserialize)]
struct GainsRecord {
    made_from: serde_json::Value,
    gains: Vec<[f64; 3]>,
    seconds: f64,
}

/// `work/raster/<epoch>.ortho-part-<i>-of-<n>.json`: the rows of tiles one unit made of an
/// epoch's mosaic, their figures, and a checksum of its PNG's pixels.
#[derive(serde::Serialize, serde::Deserialize)]
struct PartRecord {
    made_from: serde_json::Value,
    /// Rows of tiles, first and past the last.
    tile_rows: [usize; 2],
    /// The ortho rows they cover, first and past the last.
    rows: [usize; 2],
    figures: Vec<PartFigures>,
    /// FNV-1a of the RGBA samples, hex (the record's own seal is `checksum`).
    pixels_fnv1a: String,
    seconds: f64,
}

/// One tile row's [`TileRowFigures`], as recorded.
#[derive(Clone, Copy, serde::Serialize, serde::Deserialize)]
struct PartFigures {
    painted_cells: usize,
    seam_sum: f64,
    seam_pairs: usize,
    interior_sum: f64,
    interior_pairs: usize,
}

impl From<TileRowFigures> for PartFigures {
    fn from(f: TileRowFigures) -> Self {
        PartFigures {
            painted_cells: f.painted_cells,
            seam_sum: f.seam_sum,
            seam_pairs: f.seam_pairs,
            interior_sum: f.interior_sum,
            interior_pairs: f.interior_pairs,
        }
    }
}

impl From<PartFigures> for TileRowFigures {
    fn from(f: PartFigures) -> Self {
        TileRowFigures {
            painted_cells: f.painted_cells,
            seam_sum: f.seam_sum,
            seam_pairs: f.seam_pairs,
            interior_sum: f.interior_sum,
            interior_pairs: f.interior_pairs,
        }
    }
}

fn checksum(rgba: &[u8]) -> String {
    format!("{:016x}", timesift_io::fingerprint::Fnv1a::of(rgba))
}

/// Where unit `part` keeps its part of epoch `name`'s mosaic: the PNG and its record.
fn part_paths(project: &Project, name: &str, part: Part) -> (PathBuf, PathBuf) {
    let kind = format!("ortho-part-{}-of-{}", part.index, part.count);
    let record = project.layout().raster_settings(name, &kind);
    (record.with_extension("png"), record)
}

/// The rows of tiles `rows` of `epoch`'s mosaic, made with its recorded gains and written as
/// unit `part`'s part; the files written.
fn write_part(
    project: &Project,
    context: &OrthoContext,
    epoch: &EpochOrtho,
    part: Part,
    rows: std::ops::Range<usize>,
) -> Result<Vec<PathBuf>, ProjectError> {
    let gains_path = project.layout().raster_settings(&epoch.name, "ortho-gains");
    let gains = read_sealed_json::<GainsRecord>(&gains_path)
        .ok()
        .filter(|g| g.made_from == epoch.settings)
        .ok_or_else(|| ProjectError::Path {
            path: gains_path.clone(),
            message: "missing, unreadable or made from other settings: the ortho-gains step \
                      comes first (timesift task ortho-gains)"
                .into(),
        })?;
    let mosaic = epoch.mosaic(context)?;
    let cache = epoch.images(project, context);
    let start = Instant::now();
    let width = mosaic.lattice().width();
    let ortho_rows = mosaic.ortho_rows(rows.clone());
    let mut rgba = Vec::with_capacity(ortho_rows.len() * width * 4);
    let figures = mosaic
        .make_rows(
            rows.clone(),
            &cache,
            &gains.gains,
            &|_, _| {},
            &mut |_, band| {
                rgba.extend_from_slice(band);
                Ok(())
            },
        )
        .map_err(|e| epoch.error(e))?;
    let (png, record) = part_paths(project, &epoch.name, part);
    timesift_io::image::write_png(&png, width as u32, ortho_rows.len() as u32, 4, &rgba)?;
    write_sealed_json(
        &record,
        &PartRecord {
            made_from: epoch.settings.clone(),
            tile_rows: [rows.start, rows.end],
            rows: [ortho_rows.start, ortho_rows.end],
            figures: figures.into_iter().map(PartFigures::from).collect(),
            pixels_fnv1a: checksum(&rgba),
            seconds: start.elapsed().as_secs_f64(),
        },
    )?;
    Ok(vec![png, record])
}

/// `epoch`'s orthomosaic from the parts on disk that cover its rows of tiles once with the
/// current settings (of the one split that does, the finest), and its record.
fn merge_parts(
    project: &Project,
    context: &OrthoContext,
    epoch: &EpochOrtho,
) -> Result<(), ProjectError> {
    let tile_rows = tile_rows_of(project, context);
    let prefix = format!("{}.ortho-part-", epoch.name);
    let dir = project.layout().work_dir().join("raster");
    // Every part of the current settings, by split: count → (index → record).
    let mut splits: BTreeMap<usize, BTreeMap<usize, PartRecord>> = BTreeMap::new();
    for entry in std::fs::read_dir(&dir)
        .map_err(|e| timesift_io::IoError::io(&dir, e))?
        .flatten()
    {
        let file = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = file
            .strip_prefix(&prefix)
            .and_then(|r| r.strip_suffix(".json"))
        else {
            continue;
        };
        let Some((index, count)) = rest.split_once("-of-") else {
            continue;
        };
        let (Ok(index), Ok(count)) = (index.parse::<usize>(), count.parse::<usize>()) else {
            continue;
        };
        if let Ok(record) = read_sealed_json::<PartRecord>(&entry.path())
            && record.made_from == epoch.settings
        {
            splits.entry(count).or_default().insert(index, record);
        }
    }
    let covering = splits.iter().rev().find(|(_, parts)| {
        let mut next = 0;
        for r in parts.values() {
            if r.tile_rows[0] != next {
                return false;
            }
            next = r.tile_rows[1];
        }
        next == tile_rows
    });
    let Some((&count, parts)) = covering else {
        let found: Vec<String> = splits
            .iter()
            .flat_map(|(count, parts)| {
                parts.iter().map(move |(index, r)| {
                    format!(
                        "{index}/{count}: rows {}..{}",
                        r.tile_rows[0], r.tile_rows[1]
                    )
                })
            })
            .collect();
        return Err(stage_error(
            "ortho",
            format!(
                "epoch \"{}\": the parts of its orthomosaic under {} do not cover its {tile_rows} \
                 rows of tiles with the current settings (found {}): run the ortho step again \
                 (timesift task ortho)",
                epoch.name,
                dir.display(),
                match found.is_empty() {
                    true => "none".to_string(),
                    false => found.join(", "),
                }
            ),
        ));
    };
    let start = Instant::now();
    let mut writer = OrthoWriter::create(project, context, &epoch.name)?;
    let width = context.grid.ortho().width();
    let band_rows = epoch.options.tile * epoch.options.factor;
    let mut figures = Vec::with_capacity(tile_rows);
    let mut seconds = read_sealed_json::<GainsRecord>(
        &project.layout().raster_settings(&epoch.name, "ortho-gains"),
    )
    .map_or(0.0, |g| g.seconds);
    for (&index, record) in parts {
        let (png, _) = part_paths(project, &epoch.name, Part { index, count });
        let (w, h, rgba) = timesift_io::image::read_rgba8(&png)?;
        let rows = record.rows[1] - record.rows[0];
        if (w as usize, h as usize) != (width, rows) || checksum(&rgba) != record.pixels_fnv1a {
            return Err(ProjectError::Path {
                path: png,
                message: format!(
                    "not the part its record describes ({w} × {h} pixels, checksum): run the \
                     ortho step again"
                ),
            });
        }
        // Handed to the writer a tile row at a time, as the whole mosaic hands them.
        for band in rgba.chunks(band_rows * width * 4) {
            writer.push(band).map_err(|e| stage_error("ortho", e))?;
        }
        figures.extend(record.figures.iter().map(|f| TileRowFigures::from(*f)));
        seconds += record.seconds;
    }
    writer.finish(
        project,
        epoch,
        &figures,
        seconds + start.elapsed().as_secs_f64(),
    )
}
