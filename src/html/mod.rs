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

mod figures;
mod page;
mod svg;

use std::collections::BTreeMap;
use std::fmt::Write as _;

use image::ImageEncoder;
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
            orientation_section(project, &inputs, frame, &mut warnings),
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
            change_section(project, &mut warnings),
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

/// Median height of the tie points an epoch observes: the plane the footprints are cast on.
fn ground_height(inputs: &Inputs, epoch: usize) -> f64 {
    let Some((_, points)) = &inputs.ties else {
        return 0.0;
    };
    let mut z: Vec<f64> = points
        .iter()
        .filter(|p| p.epochs & (1 << epoch) != 0)
        .map(|p| p.position.z)
        .collect();
    if z.is_empty() {
        return 0.0;
    }
    z.sort_by(f64::total_cmp);
    z[z.len() / 2]
}

fn footprint_overlay(frame: &MapFrame, prints: &[Footprint]) -> String {
    let u = frame.unit();
    let mut s = String::new();
    for f in prints {
        if let Some(outline) = &f.outline {
            let pts: Vec<String> = outline
                .iter()
                .map(|p| {
                    let (x, y) = frame.at(p[0], p[1]);
                    format!("{x:.1},{y:.1}")
                })
                .collect();
            let _ = write!(
                s,
                "<polygon points=\"{}\" fill=\"#2c6e91\" fill-opacity=\"0.06\" stroke=\"#2c6e91\" \
                 stroke-opacity=\"0.7\" stroke-width=\"{:.2}\"/>",
                pts.join(" "),
                u
            );
        }
    }
    for f in prints {
        let (x, y) = frame.at(f.centre[0], f.centre[1]);
        let _ = write!(
            s,
            "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"{:.2}\" fill=\"#d35400\" stroke=\"#fff\" \
             stroke-width=\"{:.2}\"/>",
            3.0 * u,
            u
        );
    }
    s
}

fn overlap_figure(project: &Project, inputs: &Inputs, epoch: &str) -> String {
    let layout = project.layout();
    let (Some(recon), Ok(dem)) = (&inputs.recon, read_f32(&layout.dem(epoch))) else {
        return "<p class=\"missing\">Overlap map: needs the DEM (dem stage).</p>".into();
    };
    let step = dem.width.max(dem.height).div_ceil(300).max(1);
    let (cols, rows, counts) = figures::overlap(&dem, recon, epoch, step);
    let mut rgba = Vec::with_capacity(cols * rows * 4);
    for c in &counts {
        match c {
            Some(n) => {
                let [r, g, b] = overlap_colour(*n);
                rgba.extend([r, g, b, 255]);
            }
            None => rgba.extend([0, 0, 0, 0]),
        }
    }
    let mut png = Vec::new();
    let encoded = image::codecs::png::PngEncoder::new(&mut png).write_image(
        &rgba,
        cols as u32,
        rows as u32,
        image::ExtendedColorType::Rgba8,
    );
    if encoded.is_err() {
        return "<p class=\"missing\">Overlap map could not be encoded.</p>".into();
    }
    let measured: Vec<u16> = counts.iter().flatten().copied().collect();
    let thin = measured.iter().filter(|&&n| n < 3).count();
    let legend: String = OVERLAP_LEGEND
        .iter()
        .map(|(n, label)| {
            let [r, g, b] = overlap_colour(*n);
            format!("<span style=\"background:rgb({r},{g},{b})\">{label}</span>")
        })
        .collect();
    format!(
        "<figure>{}<figcaption>Images seeing each DEM cell (occlusion ignored). {} % of the \
         cells are seen by fewer than 3 images. <span class=\"legend\">{legend}</span>\
         </figcaption></figure>",
        img(
            Some(&page::data_uri("image/png", &png)),
            &format!("overlap map of {epoch}"),
            "map"
        ),
        num(Some(100.0 * thin as f64 / measured.len().max(1) as f64), 1)
    )
}

fn residual_rows(kind: &str, r: &PointResiduals, rows: &mut Vec<Vec<String>>) {
    for p in &r.points {
        rows.push(vec![
            format!("{} {}", esc(kind), esc(&p.name)),
            p.images.to_string(),
            mm(p.de, 1),
            mm(p.dn, 1),
            mm(p.dh, 1),
            mm(p.markers_sigma.map(|s| s[2]), 1),
        ]);
    }
    if let Some(rmse) = &r.rmse {
        rows.push(vec![
            format!("<i>{} RMSE ({} points)</i>", esc(kind), rmse.n),
            String::new(),
            mm(Some(rmse.de), 1),
            mm(Some(rmse.dn), 1),
            mm(Some(rmse.dh), 1),
            String::new(),
        ]);
    }
}

/// The check points' RMSE from their markers alone, as a row of [`residual_rows`]' table. Not
/// for control points: the adjustment fits them, so their residuals fall below it.
fn markers_rmse_row(check: &PointResiduals) -> Option<Vec<String>> {
    let rmse = check.markers_rmse?;
    Some(vec![
        "<i>check RMSE from the markers alone</i>".into(),
        String::new(),
        mm(Some(rmse.de), 1),
        mm(Some(rmse.dn), 1),
        mm(Some(rmse.dh), 1),
        String::new(),
    ])
}

fn residual_map(
    project: &Project,
    frame: &MapFrame,
    background: Option<&str>,
    control: &PointResiduals,
    check: &PointResiduals,
) -> Option<String> {
    let position = |name: &str| {
        project
            .gcps
            .iter()
            .chain(&project.checkpoints)
            .find(|c| c.name == name)
            .map(|c| c.position)
    };
    let vectors: Vec<(bool, [f64; 2], [f64; 2])> = [(true, control), (false, check)]
        .iter()
        .flat_map(|(is_control, r)| {
            r.points.iter().filter_map(move |p| {
                let v = p.vector()?;
                let at = position(&p.name)?;
                Some((*is_control, [at.x, at.y], [v[0], v[1]]))
            })
        })
        .collect();
    if vectors.is_empty() {
        return None;
    }
    let longest = vectors
        .iter()
        .map(|v| v.2[0].hypot(v.2[1]))
        .fold(0.0f64, f64::max)
        .max(1e-6);
    // The longest arrow a tenth of the frame's width.
    let scale = frame.width * frame.cell * 0.1 / longest;
    let u = frame.unit();
    let mut s = String::new();
    for (is_control, at, d) in &vectors {
        let colour = if *is_control { "#1f5fbf" } else { "#e67e22" };
        let (x0, y0) = frame.at(at[0], at[1]);
        let (x1, y1) = frame.at(at[0] + d[0] * scale, at[1] + d[1] * scale);
        let _ = write!(
            s,
            "<circle cx=\"{x0:.1}\" cy=\"{y0:.1}\" r=\"{:.2}\" fill=\"{colour}\"/>\
             <line x1=\"{x0:.1}\" y1=\"{y0:.1}\" x2=\"{x1:.1}\" y2=\"{y1:.1}\" stroke=\"{colour}\" \
             stroke-width=\"{:.2}\"/>",
            2.5 * u,
            1.5 * u
        );
    }
    Some(format!(
        "<figure>{}<figcaption>Horizontal residuals (intersected − surveyed) of control \
         (<span style=\"color:#1f5fbf\">blue</span>) and check points \
         (<span style=\"color:#e67e22\">orange</span>), drawn × {:.0}: the longest is {} mm.\
         </figcaption></figure>",
        frame.svg(background, &s),
        scale,
        mm(Some(longest), 1)
    ))
}

/// A datum tilt the control leaves looser than this (σ, mm/m) is named among the warnings.
const DATUM_TILT_WARNING_MM_PER_M: f64 = 1.0;

fn orientation_section(
    project: &Project,
    inputs: &Inputs,
    frame: Option<MapFrame>,
    warnings: &mut Vec<String>,
) -> String {
    let a = &inputs.align;
    let mut rows = Vec::new();
    for e in &project.epochs {
        let Some(r) = a.epochs.get(&e.name) else {
            continue;
        };
        rows.push(orientation_row(&e.name, r));
        orientation_warnings(&e.name, r, warnings);
    }
    let mut s = table(
        &[
            "epoch",
            "images",
            "oriented",
            "RMS px",
            "tie points",
            "inter-epoch",
            "control RMSE dE/dN/dH mm",
            "check RMSE dE/dN/dH mm",
            "GNSS offset E/N/H m",
            "datum tilt σ mm/m: loosest / firmest",
        ],
        &rows,
    );
    let errors = match (&inputs.colmap, &inputs.recon) {
        (Some(model), Some(recon)) => figures::reprojection_errors(model, recon),
        _ => BTreeMap::new(),
    };
    for k in 0..project.epochs.len() {
        s.push_str(&epoch_orientation(project, inputs, frame, &errors, k));
    }
    s
}

/// One epoch's row of the orientation table.
fn orientation_row(name: &str, r: &EpochOrientation) -> Vec<String> {
    let rmse = |p: &PointResiduals| {
        p.rmse.map_or("–".into(), |r| {
            format!(
                "{} / {} / {}",
                mm(Some(r.de), 1),
                mm(Some(r.dn), 1),
                mm(Some(r.dh), 1)
            )
        })
    };
    vec![
        esc(name),
        r.images_given.to_string(),
        r.images_oriented.to_string(),
        num(r.rms_reprojection_px, 3),
        r.tie_points.to_string(),
        r.inter_epoch_tie_points.to_string(),
        rmse(&r.control_points),
        rmse(&r.check_points),
        r.gnss_offset.map_or("–".into(), |o| {
            let std = o.std.map_or(String::new(), |s| {
                format!(" ± {:.2} / {:.2} / {:.2}", s[0], s[1], s[2])
            });
            let within = o.within_flight_sigma_m.map_or(String::new(), |s| {
                let weighs = if o.scatter_weighs_priors {
                    ", weighing its priors"
                } else {
                    ""
                };
                format!(
                    " (scatter within the flight {:.2} / {:.2}{weighs})",
                    s[0], s[1]
                )
            });
            format!(
                "{:.2} / {:.2} / {:.2}{std}{within}",
                o.offset[0], o.offset[1], o.offset[2]
            )
        }),
        r.datum_tilt.map_or("–".into(), |t| {
            format!(
                "{:.2} (gradient at {:.0}°) / {:.2}",
                t.sigma_max_mm_per_m, t.loose_azimuth_deg, t.sigma_min_mm_per_m
            )
        }),
    ]
}

/// The warnings one epoch's orientation calls for: a loose datum tilt, a GNSS offset the focal
/// length cannot be told from, images not oriented.
fn orientation_warnings(name: &str, r: &EpochOrientation, warnings: &mut Vec<String>) {
    if let Some(t) = r
        .datum_tilt
        .filter(|t| t.sigma_max_mm_per_m >= DATUM_TILT_WARNING_MM_PER_M)
    {
        warnings.push(format!(
            "epoch {}: its control fixes the datum's tilt only to ± {:.1} mm/m (σ, gradient \
             at {:.0}° from east): ± {:.2} m of false change per 100 m across that direction \
             in a DoD, which check points along the other direction cannot show; control \
             points spread across the site (or more accurate GNSS) fix it",
            name,
            t.sigma_max_mm_per_m,
            t.loose_azimuth_deg,
            t.sigma_max_mm_per_m / 10.0
        ));
    }
    if let Some(rho) = r
        .gnss_offset
        .and_then(|o| o.focal_correlation)
        .filter(|rho| *rho > FOCAL_CORRELATION_WARNING)
    {
        warnings.push(format!(
            "epoch {}: the vertical GNSS offset correlates with the focal length (|ρ| = \
             {rho:.2}): nadir images over flat ground cannot tell a flying-height bias from a \
             focal length, so the offset's prior (the stated GNSS accuracy) decides it; \
             control points with height spread, oblique images or a calibrated camera \
             separate them",
            name
        ));
    }
    if r.images_oriented < r.images_given {
        warnings.push(format!(
            "epoch {}: {} of {} images could not be oriented",
            name,
            r.images_given - r.images_oriented,
            r.images_given
        ));
    }
}

/// One epoch's figures (footprints, overlap, reprojection errors, residual map) and its table
/// of control and check points.
fn epoch_orientation(
    project: &Project,
    inputs: &Inputs,
    frame: Option<MapFrame>,
    errors: &BTreeMap<String, Vec<f64>>,
    k: usize,
) -> String {
    let a = &inputs.align;
    let e = &project.epochs[k];
    let mut s = String::new();
    let _ = write!(s, "<h3>Epoch {}</h3><div class=\"row\">", esc(&e.name));
    let background = inputs.hillshade(&e.name);
    if let (Some(frame), Some(recon)) = (frame, &inputs.recon) {
        let prints = figures::footprints(recon, &e.name, ground_height(inputs, k));
        let _ = write!(
            s,
            "<figure>{}<figcaption>{} camera positions (orange) and image footprints on the \
             plane of the median tie-point height, over the DEM hillshade.</figcaption>\
             </figure>",
            frame.svg(background, &footprint_overlay(&frame, &prints)),
            prints.len()
        );
    }
    s.push_str(&overlap_figure(project, inputs, &e.name));
    s.push_str("</div><div class=\"row\">");
    match errors.get(&e.name).filter(|v| !v.is_empty()) {
        Some(v) => {
            let mut sorted = v.clone();
            sorted.sort_by(f64::total_cmp);
            let q = |f: f64| sorted[((sorted.len() - 1) as f64 * f).round() as usize];
            let rms = (sorted.iter().map(|x| x * x).sum::<f64>() / sorted.len() as f64).sqrt();
            let hi = (q(0.99) * 1.1).max(1e-3);
            let _ = write!(
                s,
                "<figure>{}<figcaption>Reprojection error of the epoch's {} observations: \
                 median {} px, RMS {} px, 95th percentile {} px.</figcaption></figure>",
                svg::histogram(
                    &sorted,
                    0.0,
                    hi,
                    "reprojection error (px)",
                    &[(q(0.5), "median"), (q(0.95), "95 %")]
                ),
                sorted.len(),
                num(Some(q(0.5)), 3),
                num(Some(rms), 3),
                num(Some(q(0.95)), 3)
            );
        }
        None => s.push_str("<p class=\"missing\">No observations in out/colmap/.</p>"),
    }
    if let (Some(frame), Some(r)) = (frame, a.epochs.get(&e.name))
        && let Some(fig) = residual_map(
            project,
            &frame,
            background,
            &r.control_points,
            &r.check_points,
        )
    {
        s.push_str(&fig);
    }
    s.push_str("</div>");
    if let Some(r) = a.epochs.get(&e.name) {
        let mut rows = Vec::new();
        residual_rows("control", &r.control_points, &mut rows);
        residual_rows("check", &r.check_points, &mut rows);
        rows.extend(markers_rmse_row(&r.check_points));
        if !rows.is_empty() {
            s.push_str(&table(
                &[
                    "point",
                    "images",
                    "dE mm",
                    "dN mm",
                    "dH mm",
                    "σH of its markers mm",
                ],
                &rows,
            ));
            s.push_str(
                "<p>σH of its markers: the standard deviation of the point's intersected height \
                 that its markers' stated accuracy alone gives through these cameras. The \
                 check RMSE from the markers alone is what the check points would show, in \
                 expectation, with a perfect orientation: a check RMSE near it cannot tell \
                 this orientation from a better one.</p>",
            );
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
                .filter(|p| p.epochs & (1 << e) != 0 && p.epochs & !(1u32 << e) != 0)
                .count();
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
    let inter: Vec<&TiePoint> = points
        .iter()
        .filter(|p| p.epochs.count_ones() > 1)
        .collect();
    // At most 20 000 dots, every k-th point.
    let stride = inter.len().div_ceil(20_000).max(1);
    let mut overlay = String::new();
    for p in inter.iter().step_by(stride) {
        let (x, y) = frame.at(p.position.x, p.position.y);
        let colour = match p.epochs.count_ones() {
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

fn volume_row(label: &str, v: &timesift_change::volume::Volumes) -> Vec<String> {
    vec![
        esc(label),
        num(Some(v.cut), 1),
        num(Some(v.fill), 1),
        format!("{} ± {}", num(Some(v.net), 1), num(Some(v.sigma_net), 1)),
        num(Some(v.area), 0),
        v.changed_cells.to_string(),
    ]
}

fn change_section(project: &Project, warnings: &mut Vec<String>) -> String {
    let layout = project.layout();
    let mut s = String::from(
        "<p>Later minus earlier: red where the ground rose, blue where it lowered; cells within \
         the 95 % level of detection (LoD95) are grey. Statistics over the stable areas measure \
         how well the epochs are co-registered: a median and a plane near zero are what the \
         Time-SIFT block should deliver without any co-registration step.</p>",
    );
    for (a, b) in epoch_pairs(project) {
        let dir = layout.change_dir(&a, &b);
        let _ = write!(s, "<h3>{} → {}</h3>", esc(&a), esc(&b));
        let stats_path = layout.change_stats(&a, &b);
        let dem = match read_json::<DemReport>(&stats_path) {
            Ok(dem) => dem,
            Err(_) if !stats_path.exists() => {
                s.push_str("<p class=\"missing\">Not computed (change stage).</p>");
                continue;
            }
            Err(e) => {
                warnings.push(e.to_string());
                let _ = write!(s, "<p class=\"missing\">{}</p>", esc(&e.to_string()));
                continue;
            }
        };
        s.push_str(&dod_statistics(&a, &b, &dem, warnings));
        s.push_str(&dod_volumes_and_maps(&dir, &dem));
        for w in &dem.warnings {
            warnings.push(format!("{a} → {b}: {w}"));
        }
        s.push_str(&m3c2_summary(&dir, &layout.m3c2_stats(&a, &b)));
    }
    s
}

/// A DoD's statistics (every cell, the stable areas), the stable areas' plane (a warning where
/// it tilts by more than the LoD95), the LoD95 and the correlation of the stable errors.
fn dod_statistics(a: &str, b: &str, dem: &DemReport, warnings: &mut Vec<String>) -> String {
    let mut s = String::new();
    let mut rows = vec![stat_row("all cells", &dem.all)];
    if let Some(st) = &dem.stable {
        rows.push(stat_row("stable areas", st));
    }
    s.push_str(&table(
        &[
            "cells", "count", "mean m", "median m", "NMAD m", "std m", "RMSE m",
        ],
        &rows,
    ));
    match &dem.stable_trend {
        Some(t) => {
            let _ = write!(
                s,
                "<p>Plane through the stable areas: {} mm/m towards {}°, a gain of {} m \
                 across their {} m extent.</p>",
                num(Some(t.slope * 1000.0), 2),
                num(Some(t.azimuth_deg), 0),
                num(Some(t.gain_m), 3),
                num(Some(t.extent_m), 0)
            );
            if let Some(lod) = dem.lod95
                && t.gain_m > lod
            {
                warnings.push(format!(
                    "{a} → {b}: the stable areas tilt by {:.3} m across {:.0} m, more than \
                     the LoD95 of {:.3} m: the epochs are not co-registered to the level of \
                     detection there",
                    t.gain_m, t.extent_m, lod
                ));
            }
        }
        None => s.push_str(
            "<p class=\"missing\">No stable areas given: co-registration cannot be judged.</p>",
        ),
    }
    let _ = write!(
        s,
        "<p>LoD95 {} m ({}); {} cells beyond it.</p>",
        num(dem.lod95, 3),
        esc(&dem.lod_source),
        dem.significant_cells.map_or("–".into(), |c| c.to_string())
    );
    match &dem.stable_variogram {
        Some(v) => {
            let c = v.correlation();
            let _ = write!(
                s,
                "<p>Errors over the stable areas correlate up to {} m ({} % of their \
                 variance; spherical variogram over {} lags): the volumes' σ follows.</p>",
                num(Some(c.range_m), 1),
                num(Some(100.0 * c.correlated_fraction), 0),
                v.lags.len()
            );
        }
        None if dem.stable.is_some() => s.push_str(
            "<p class=\"missing\">No variogram of the stable areas: the volumes' σ assumes \
             independent cells and is too small.</p>",
        ),
        None => {}
    }
    s
}

/// A DoD's volumes, its map and its histogram.
fn dod_volumes_and_maps(dir: &std::path::Path, dem: &DemReport) -> String {
    let mut s = String::new();
    let mut vrows = vec![volume_row("every cell", &dem.volumes)];
    if let Some(v) = &dem.volumes_beyond_lod {
        vrows.push(volume_row("beyond LoD95", v));
    }
    s.push_str(&table(
        &[
            "volumes",
            "cut m³",
            "fill m³",
            "net m³ ± σ",
            "area m²",
            "cells",
        ],
        &vrows,
    ));
    let (map, hist) = (
        page::png_file_uri(&dir.join("dod.png")),
        page::png_file_uri(&dir.join("histogram.png")),
    );
    s.push_str(&figure_row(&[
        (
            map.as_deref(),
            "DoD map",
            "map",
            "DEM of difference, LoD95 mask in grey",
        ),
        (
            hist.as_deref(),
            "DoD histogram",
            "plot",
            "Histogram of the difference",
        ),
    ]));
    s
}

/// The M3C2 comparison of the dense clouds, from its statistics file.
fn m3c2_summary(dir: &std::path::Path, stats: &std::path::Path) -> String {
    let mut s = String::new();
    match read_json::<CloudReport>(stats) {
        Ok(c) => {
            let _ = write!(
                s,
                "<p>M3C2 between the dense clouds: {} core points, {} with a distance, {} with \
                 significant change; distance median {} m, NMAD {} m; median LoD95 {} m.</p>",
                c.core_points,
                c.defined,
                c.significant,
                num(c.distance.map(|d| d.median), 3),
                num(c.distance.map(|d| d.nmad), 3),
                num(c.lod95.map(|d| d.median), 3),
            );
            let (map, hist) = (
                page::png_file_uri(&dir.join("m3c2.png")),
                page::png_file_uri(&dir.join("m3c2_histogram.png")),
            );
            s.push_str(&figure_row(&[
                (map.as_deref(), "M3C2 map", "map", "M3C2 distances"),
                (hist.as_deref(), "M3C2 histogram", "plot", "M3C2 histogram"),
            ]));
        }
        Err(_) => {
            s.push_str("<p class=\"missing\">M3C2: not computed (needs both dense clouds).</p>")
        }
    }
    s
}

fn stat_row(label: &str, st: &timesift_change::stats::Statistics) -> Vec<String> {
    vec![
        esc(label),
        st.count.to_string(),
        num(Some(st.mean), 4),
        num(Some(st.median), 4),
        num(Some(st.nmad), 4),
        num(Some(st.std), 4),
        num(Some(st.rmse), 4),
    ]
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
