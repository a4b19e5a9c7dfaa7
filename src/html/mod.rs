//! `out/report.html`: one self-contained page for people deciding whether they can trust the
//! change they see. Every figure is inlined (PNG as data URIs, plots as SVG), so the file opens
//! from a USB stick with no network.
//!
//! The page reads the products of the earlier stages through their typed reports; a stage that
//! has not run leaves its section saying so rather than failing the report. Sections (HTML ids):
//! `summary` (and the warnings gathered below), `orientation` (per epoch: images, residuals,
//! camera footprints and overlap over the hillshade, reprojection errors, ground-point residual
//! vectors), `connectivity` (inter-epoch tie points: matrix and map), `products` (DEM hillshade
//! and ortho per epoch on one extent), `change` (per pair: DoD with its LoD95 mask, histogram,
//! stable-area statistics and plane, volumes, M3C2) and `settings` (options, version, time per
//! stage).

mod change;
mod figures;
mod orientation;
mod page;
mod svg;

use std::collections::BTreeMap;
use std::fmt::Write as _;

use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_io::colmap::{ColmapModel, read_colmap_text};
use timesift_io::geotiff::read_f32;
use timesift_io::ply::{TiePoint, read_tiepoints};

use crate::commands::compare::{CloudReport, DemReport};
use crate::layout::Layout;
use crate::report::{
    AlignReport, DenseReport, EpochOrientation, FOCAL_CORRELATION_WARNING, GridFile,
    PointResiduals, RasterReport, RunLog, read_json,
};
use crate::stages::{Stage, epoch_pairs};
use crate::{Project, ProjectError};
use figures::{Footprint, OVERLAP_LEGEND, overlap_colour};
use page::{esc, figure_row, img, mm, num, table};
use svg::MapFrame;

/// The page's sections (HTML ids), in order.
pub const SECTIONS: [&str; 6] = [
    "summary",
    "orientation",
    "connectivity",
    "products",
    "change",
    "settings",
];

/// An epoch tied to the others by fewer inter-epoch tie points than this is flagged.
pub const FEW_INTER_EPOCH_TIES: usize = 100;

/// Inter-epoch tie points spanning less than this fraction of their epoch's tie-point extent
/// leave a tilt of the epoch weakly constrained: flagged.
pub const NARROW_TIE_SPREAD: f64 = 0.25;

/// What the page was built from, and what it warns about.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReportPage {
    /// The page.
    pub html: String,
    /// The warnings shown at the top.
    pub warnings: Vec<String>,
    /// The section ids present.
    pub sections: Vec<&'static str>,
}

/// The products the page reads; each optional but the orientation report.
struct Inputs {
    align: AlignReport,
    recon: Option<Reconstruction>,
    colmap: Option<ColmapModel>,
    ties: Option<(Vec<String>, Vec<TiePoint>)>,
    grid: Option<GridFile>,
    dense: Option<DenseReport>,
    raster: Option<RasterReport>,
    run: RunLog,
    /// Each epoch's hillshade preview as a data URI, read once: several maps draw over it.
    hillshades: BTreeMap<String, Option<String>>,
}

impl Inputs {
    /// The hillshade of an epoch, when its DEM exists.
    fn hillshade(&self, epoch: &str) -> Option<&str> {
        self.hillshades.get(epoch).and_then(|u| u.as_deref())
    }

    fn read(project: &Project, layout: &Layout) -> Result<Inputs, ProjectError> {
        Ok(Inputs {
            hillshades: project
                .epochs
                .iter()
                .map(|e| {
                    (
                        e.name.clone(),
                        page::png_file_uri(&layout.dem_preview(&e.name)),
                    )
                })
                .collect(),
            align: read_json(&layout.report_json())?,
            recon: read_cameras_json(&layout.cameras_json()).ok(),
            colmap: read_colmap_text(&layout.colmap_dir()).ok(),
            ties: read_tiepoints(&layout.tiepoints_ply()).ok(),
            grid: read_json(&layout.grid_json()).ok(),
            dense: read_json(&layout.dense_report()).ok(),
            raster: read_json(&layout.raster_report()).ok(),
            run: read_json(&layout.run_log()).unwrap_or_default(),
        })
    }
}

/// Builds the report page of a project whose align stage has run.
pub fn build_report(project: &Project) -> Result<ReportPage, ProjectError> {
    let layout = project.layout();
    let inputs = Inputs::read(project, &layout)?;
    let mut warnings = Vec::new();
    let frame = map_frame(&inputs);
    let mut body = String::new();
    let sections: Vec<(&'static str, &str, String)> = vec![
        (
            "orientation",
            "Orientation per epoch",
            orientation::orientation_section(project, &inputs, frame, &mut warnings),
        ),
        (
            "connectivity",
            "Epoch connectivity",
            connectivity_section(project, &inputs, frame, &mut warnings),
        ),
        (
            "products",
            "DEMs and orthomosaics",
            products_section(project, &inputs),
        ),
        (
            "change",
            "Change between epochs",
            change::change_section(project, &inputs.align, &mut warnings),
        ),
        (
            "settings",
            "Settings and run",
            settings_section(project, &inputs),
        ),
    ];
    let summary = summary_section(&inputs, &warnings);
    let mut ids = vec!["summary"];
    let _ = write!(
        body,
        "<section id=\"summary\"><h2>Summary</h2>{summary}</section>"
    );
    for (id, title, html) in &sections {
        ids.push(id);
        let _ = write!(
            body,
            "<section id=\"{id}\"><h2>{}</h2>{html}</section>",
            esc(title)
        );
    }
    let nav: String = std::iter::once(("summary", "Summary"))
        .chain(sections.iter().map(|(id, t, _)| (*id, *t)))
        .map(|(id, t)| format!("<a href=\"#{id}\">{}</a>", esc(t)))
        .collect();
    let title = project
        .dir
        .canonicalize()
        .ok()
        .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| "project".into());
    let html = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>timesift report: {t}</title><style>{style}</style></head><body>\
         <h1>timesift report: {t}</h1><p class=\"meta\">timesift {v}, method <b>{m}</b>, \
         {n} epochs</p><nav>{nav}</nav>{body}</body></html>\n",
        t = esc(&title),
        style = page::STYLE,
        v = env!("CARGO_PKG_VERSION"),
        m = inputs.align.method,
        n = project.epochs.len(),
    );
    debug_assert_eq!(ids, SECTIONS);
    Ok(ReportPage {
        html,
        warnings,
        sections: ids,
    })
}

/// The maps' frame: the project lattice when the DEMs exist, else the cameras' extent.
fn map_frame(inputs: &Inputs) -> Option<MapFrame> {
    if let Some(g) = &inputs.grid {
        return Some(MapFrame {
            west: g.origin[0],
            north: g.origin[1],
            cell: g.dem_cell,
            width: g.size[0] as f64,
            height: g.size[1] as f64,
        });
    }
    let recon = inputs.recon.as_ref()?;
    let centres: Vec<[f64; 2]> = recon
        .images
        .iter()
        .filter_map(|i| i.pose.as_ref().map(|p| [p.center().x, p.center().y]))
        .collect();
    if centres.is_empty() {
        return None;
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for c in &centres {
        for k in 0..2 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let pad = ((hi[0] - lo[0]).max(hi[1] - lo[1]) * 0.15).max(1.0);
    Some(MapFrame::around(
        [lo[0] - pad, lo[1] - pad],
        [hi[0] + pad, hi[1] + pad],
        600.0,
    ))
}

fn summary_section(inputs: &Inputs, warnings: &[String]) -> String {
    let a = &inputs.align;
    let mut s = format!(
        "<p>{} of {} images oriented in one run of the <b>{}</b> strategy; datum: {}; RMS \
         reprojection error {} px; {}{} tie points, of which {} split as moved between epochs \
         and {} split for lying off the stable areas{}.</p>",
        a.images_oriented,
        a.images_given,
        a.method,
        esc(&a.datum),
        num(a.rms_reprojection_px, 3),
        if a.inter_epoch_ties_joined > 0 {
            format!(
                "{} inter-epoch ties joined by descriptor after a first block, then ",
                a.inter_epoch_ties_joined
            )
        } else {
            String::new()
        },
        a.tie_points,
        a.inter_epoch_ties_split_as_moved,
        a.inter_epoch_ties_split_off_stable,
        if a.changed_regions > 0 {
            format!(
                " or on the {} regions their own differences between epochs showed changed",
                a.changed_regions
            )
        } else {
            String::new()
        }
    );
    let produced: Vec<String> = [
        (Stage::Dense, "dense clouds"),
        (Stage::Dem, "DEMs"),
        (Stage::Ortho, "orthomosaics"),
        (Stage::Change, "change products"),
    ]
    .iter()
    .filter(|(st, _)| inputs.run.stages.contains_key(st.name()))
    .map(|(_, what)| what.to_string())
    .collect();
    if !produced.is_empty() {
        let _ = write!(s, "<p>Products made: {}.</p>", produced.join(", "));
    }
    if warnings.is_empty() {
        s.push_str("<div class=\"ok\">No warning: every check below passed.</div>");
    } else {
        for w in warnings {
            let _ = write!(s, "<div class=\"warn\">{}</div>", esc(w));
        }
    }
    s
}

fn connectivity_section(
    project: &Project,
    inputs: &Inputs,
    frame: Option<MapFrame>,
    warnings: &mut Vec<String>,
) -> String {
    let Some((names, points)) = &inputs.ties else {
        return "<p class=\"missing\">out/tiepoints.ply is missing (align stage).</p>".into();
    };
    let n = names.len();
    let m = figures::tie_matrix(n, points);
    let mut s = String::from(
        "<p>Tie points observed in both epochs of each pair (the diagonal: all tie points of the \
         epoch). These points are what holds the epochs in one frame: an epoch tied by few of \
         them, or by points on a small part of the ground, can drift or tilt against the others.\
         </p>",
    );
    let rows = tie_matrix_rows(names, &m);
    let headers: Vec<&str> = std::iter::once("epoch")
        .chain(names.iter().map(String::as_str))
        .collect();
    s.push_str(&table(&headers, &rows));
    if n > 1 {
        for (e, name) in names.iter().enumerate() {
            let inter = points
                .iter()
                .filter(|p| p.epochs.contains(e) && p.epochs.has_other_than(e))
                .count();
            // An epoch held to the reference epoch's surface over its stable ground does not
            // hang on its feature ties alone (the orientation section shows that fit), nor
            // does the reference epoch when every other one is.
            let fitted = |name: &String| {
                inputs
                    .align
                    .epochs
                    .get(name)
                    .is_some_and(|r| r.surface_fit.is_some())
            };
            let reference = project.reference_epoch.index();
            let on_surface = inputs.align.surface_heights > 0
                && (fitted(name)
                    || (e == reference
                        && names.iter().enumerate().all(|(k, n)| k == e || fitted(n))));
            if on_surface {
                continue;
            }
            if inter < FEW_INTER_EPOCH_TIES {
                warnings.push(format!(
                    "epoch {name} hangs on {inter} inter-epoch tie points (fewer than \
                     {FEW_INTER_EPOCH_TIES}): its position relative to the other epochs is weakly \
                     determined"
                ));
            }
            if let Some(spread) = figures::tie_spread(points, e)
                && spread < NARROW_TIE_SPREAD
            {
                warnings.push(format!(
                    "epoch {name}: its inter-epoch tie points span {:.0} % of its tie-point \
                     extent: a tilt of the epoch about them is weakly determined; check the \
                     stable-area plane of its DoDs",
                    100.0 * spread
                ));
            }
        }
    }
    if let Some(frame) = frame {
        s.push_str(&tie_map(project, inputs, frame, points));
    }
    s
}

/// The rows of the inter-epoch tie matrix, each count shaded by its share of the largest.
fn tie_matrix_rows(names: &[String], m: &[Vec<usize>]) -> Vec<Vec<String>> {
    let n = names.len();
    let max_off = (0..n)
        .flat_map(|a| (0..n).filter(move |&b| b != a).map(move |b| (a, b)))
        .map(|(a, b)| m[a][b])
        .max()
        .unwrap_or(0)
        .max(1);
    let mut rows = Vec::new();
    for a in 0..n {
        let mut row = vec![esc(&names[a])];
        for b in 0..n {
            let v = m[a][b];
            let shade = if a == b {
                "#f0f0f0".to_string()
            } else {
                let t = v as f64 / max_off as f64;
                format!(
                    "rgb({},{},{})",
                    (255.0 - 120.0 * t) as u8,
                    (255.0 - 60.0 * t) as u8,
                    255
                )
            };
            row.push(format!(
                "<span style=\"background:{shade};padding:0 6px\">{v}</span>"
            ));
        }
        rows.push(row);
    }
    rows
}

/// The map of where the epochs are tied, over the reference epoch's hillshade.
fn tie_map(project: &Project, inputs: &Inputs, frame: MapFrame, points: &[TiePoint]) -> String {
    let mut s = String::new();
    let u = frame.unit();
    let inter: Vec<&TiePoint> = points.iter().filter(|p| p.epochs.len() > 1).collect();
    // At most 20 000 dots, every k-th point.
    let stride = inter.len().div_ceil(20_000).max(1);
    let mut overlay = String::new();
    for p in inter.iter().step_by(stride) {
        let (x, y) = frame.at(p.position.x, p.position.y);
        let colour = match p.epochs.len() {
            2 => "#f1c40f",
            3 => "#e67e22",
            _ => "#c0392b",
        };
        let _ = write!(
            overlay,
            "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"{:.2}\" fill=\"{colour}\"/>",
            1.4 * u
        );
    }
    let reference = project
        .epochs
        .get(project.reference_epoch.0 as usize)
        .map(|e| e.name.clone())
        .unwrap_or_default();
    let background = inputs.hillshade(&reference);
    let _ = write!(
        s,
        "<div class=\"row\"><figure>{}<figcaption>Where the epochs are tied: the {} tie points \
         seen in two (yellow), three (orange) or more (red) epochs, over the hillshade of the \
         reference epoch {}.</figcaption></figure></div>",
        frame.svg(background, &overlay),
        inter.len(),
        esc(&reference)
    );
    s
}

fn products_section(project: &Project, inputs: &Inputs) -> String {
    let layout = project.layout();
    let mut s = String::new();
    if let Some(g) = &inputs.grid {
        let _ = write!(
            s,
            "<p>One lattice for every epoch ({}): DEM cells of {} m ({} × {}), ortho cells of {} m. \
             Left: DEM hillshade; right: orthomosaic; same extent.</p>",
            esc(&g.crs),
            g.dem_cell,
            g.size[0],
            g.size[1],
            g.ortho_cell
        );
    }
    for e in &project.epochs {
        let name = &e.name;
        let dense = inputs.dense.as_ref().and_then(|d| d.epochs.get(name));
        let raster = inputs.raster.as_ref().and_then(|r| r.epochs.get(name));
        let ortho = page::png_file_uri(&layout.ortho_preview(name));
        let _ = write!(
            s,
            "<h3>Epoch {}</h3><p>{} dense points (mean {} images per point{}); {} DEM cells with \
             a height ({} filled); ortho painted over {} % of them, colour step across seams {} \
             against {} within images.</p>{}",
            esc(name),
            dense.map_or("–".into(), |d| d.points.to_string()),
            num(dense.map(|d| d.mean_images_per_point), 1),
            dense
                .and_then(|d| d.refined_share)
                .map_or(String::new(), |f| format!(
                    "; {:.0} % of the depths matched again at twice the resolution",
                    100.0 * f
                )),
            raster.map_or("–".into(), |r| r.dem_cells.to_string()),
            raster.map_or("–".into(), |r| r.dem_cells_filled.to_string()),
            num(
                raster
                    .and_then(|r| r.ortho_painted_fraction)
                    .map(|f| 100.0 * f),
                1
            ),
            num(raster.and_then(|r| r.seam_jump), 1),
            num(raster.and_then(|r| r.interior_jump), 1),
            figure_row(&[
                (
                    inputs.hillshade(name),
                    &format!("DEM hillshade of {name}"),
                    "thumb",
                    "DEM hillshade"
                ),
                (
                    ortho.as_deref(),
                    &format!("orthomosaic of {name}"),
                    "thumb",
                    "Orthomosaic"
                ),
            ]),
        );
    }
    s
}

fn settings_section(project: &Project, inputs: &Inputs) -> String {
    let mut rows = Vec::new();
    let mut total = 0.0;
    for stage in Stage::ALL {
        if let Some(r) = inputs.run.stages.get(stage.name()) {
            total += r.seconds;
            rows.push(vec![
                stage.name().to_string(),
                num(Some(r.seconds), 1),
                format!("<span style=\"text-align:left\">{}</span>", esc(&r.summary)),
            ]);
        }
    }
    rows.push(vec![
        "<i>total</i>".into(),
        num(Some(total), 1),
        String::new(),
    ]);
    let config = toml::to_string(&project.config).unwrap_or_else(|e| format!("# {e}"));
    format!(
        "<p>timesift {} (run by {}). Time per stage in its latest run (a stage that found its \
         work up to date shows the time of that check):</p>{}<h3>Options used</h3><p>The \
         project's settings with every default filled in:</p><pre>{}</pre>",
        env!("CARGO_PKG_VERSION"),
        esc(if inputs.run.version.is_empty() {
            "this version"
        } else {
            &inputs.run.version
        }),
        table(&["stage", "seconds", "summary"], &rows),
        esc(&config)
    )
}
