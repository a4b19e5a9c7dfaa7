//! The report's orientation section: per epoch its images, errors, control and check points,
//! datum tilt and GNSS offset, with its figures (footprints, overlap, reprojection errors,
//! residual map) and the warnings they call for.

use super::*;

/// Median height of the tie points an epoch observes: the plane the footprints are cast on.
pub(super) fn ground_height(inputs: &Inputs, epoch: usize) -> f64 {
    let Some((_, points)) = &inputs.ties else {
        return 0.0;
    };
    let mut z: Vec<f64> = points
        .iter()
        .filter(|p| p.epochs.contains(epoch))
        .map(|p| p.position.z)
        .collect();
    if z.is_empty() {
        return 0.0;
    }
    z.sort_by(f64::total_cmp);
    z[z.len() / 2]
}

pub(super) fn footprint_overlay(frame: &MapFrame, prints: &[Footprint]) -> String {
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

pub(super) fn overlap_figure(project: &Project, inputs: &Inputs, epoch: &str) -> String {
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
    let Ok(png) = timesift_io::image::encode_png(
        std::path::Path::new("the overlap map"),
        cols as u32,
        rows as u32,
        4,
        &rgba,
    ) else {
        return "<p class=\"missing\">Overlap map could not be encoded.</p>".into();
    };
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

pub(super) fn residual_rows(kind: &str, r: &PointResiduals, rows: &mut Vec<Vec<String>>) {
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
pub(super) fn markers_rmse_row(check: &PointResiduals) -> Option<Vec<String>> {
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

pub(super) fn residual_map(
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

pub(super) fn orientation_section(
    project: &Project,
    inputs: &Inputs,
    frame: Option<MapFrame>,
    warnings: &mut Vec<String>,
) -> String {
    let a = &inputs.align;
    let mut rows = Vec::new();
    for name in &a.control_points_rejected {
        warnings.push(format!(
            "control point {name}: left out of the adjustment: where the camera priors and the \
             other control points place the block, its markers intersect far from its surveyed \
             coordinates (a typing error, another CRS, a marker on the wrong point); its \
             residual below says by how much"
        ));
    }
    for e in &project.epochs {
        let Some(r) = a.epochs.get(&e.name) else {
            continue;
        };
        rows.push(orientation_row(&e.name, r));
        orientation_warnings(&e.name, r, warnings);
        if a.not_co_registered.contains(&e.name) {
            warnings.push(not_co_registered_warning(&e.name));
        }
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
            "datum tilt σ mm/m: loosest / firmest (height σ)",
            "block tilt σ mm/m: loosest / firmest",
        ],
        &rows,
    );
    let errors = match (&inputs.colmap, &inputs.recon) {
        (Some(model), Some(recon)) => figures::reprojection_errors(model, recon),
        _ => BTreeMap::new(),
    };
    s.push_str(&surface_fit_table(project, a, warnings));
    for k in 0..project.epochs.len() {
        s.push_str(&epoch_orientation(project, inputs, frame, &errors, k));
    }
    s
}

/// Each later epoch's tie points against the reference epoch's surface, term by term; a warning
/// for each term beyond 3 σ. Empty when no epoch was compared.
fn surface_fit_table(
    project: &Project,
    a: &crate::report::AlignReport,
    warnings: &mut Vec<String>,
) -> String {
    let mut rows = Vec::new();
    for e in &project.epochs {
        let Some(f) = a.epochs.get(&e.name).and_then(|r| r.surface_fit) else {
            continue;
        };
        let terms = [
            ("offset", f.offset_m, "m", 3),
            ("slope east", f.slope_east_mm_per_m, "mm/m", 2),
            ("slope north", f.slope_north_mm_per_m, "mm/m", 2),
            ("tilt", f.tilt_mm_per_m, "mm/m", 2),
        ];
        let shape = [
            ("dome at 100 m", f.dome_mm_at_100m, "mm", 1),
            ("height scale", f.height_scale_mm_per_m, "mm/m", 2),
        ];
        let terms = terms
            .into_iter()
            .map(|(name, t, unit, digits)| (name, Some(t), unit, digits))
            .chain(shape);
        let mut row = vec![
            esc(&e.name),
            format!(
                "{} / {} / {}",
                f.points_held, f.points_kept, f.points_compared
            ),
            format!("{:.3}", f.sigma_m),
        ];
        for (name, t, unit, digits) in terms {
            let Some(t) = t else {
                row.push("–".into());
                continue;
            };
            let cell = format!("{:.*} ± {:.*}", digits, t.value, digits, t.sigma);
            if t.significant() {
                row.push(format!("<b>{cell}</b>"));
                // The tilt speaks for its two slopes.
                if name.starts_with("slope") {
                    continue;
                }
                let against = match a.reference_dem {
                    Some(_) => "the reference DEM",
                    None => "the reference epoch's surface",
                };
                // "an offset", "a tilt".
                let article = if name.starts_with(['a', 'e', 'i', 'o', 'u']) {
                    "an"
                } else {
                    "a"
                };
                warnings.push(format!(
                    "epoch {}: its tie points miss {against} by {article} {name} of \
                     {:.*} {unit} (σ {:.*}, {:.1} σ) over stable ground: its DEM and the DoDs \
                     with it carry that difference",
                    e.name,
                    digits,
                    t.value,
                    digits,
                    t.sigma,
                    t.value.abs() / t.sigma.max(f64::MIN_POSITIVE)
                ));
            } else {
                row.push(cell);
            }
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return String::new();
    }
    let mut s = match &a.reference_dem {
        Some(dem) => format!(
            "<p>Each epoch's own tie points on stable ground against the reference DEM \
             (<code>{}</code>), their height misses decomposed term by term with σ, from the \
             points never held to it; {} others held to it by height observations on its \
             tangent plane. Bold: beyond 3 σ.</p>",
            esc(dem),
            a.surface_heights
        ),
        None => format!(
            "<p>Each later epoch's own tie points on stable ground against the reference \
             epoch's surface (a local plane through its tie points), their height misses \
             decomposed term by term with σ; {} of them held to it by height observations \
             (surface ties). Bold: beyond 3 σ.</p>",
            a.surface_heights
        ),
    };
    s.push_str(&table(
        &[
            "epoch",
            "points held / kept / compared",
            "σ of one point m",
            "offset m",
            "slope east mm/m",
            "slope north mm/m",
            "tilt mm/m",
            "dome at 100 m mm",
            "height scale mm/m",
        ],
        &rows,
    ));
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
        tilt_cell(r.datum_tilt),
        tilt_cell(r.block_tilt),
    ]
}

/// A tilt σ: loosest (with its gradient's direction) / firmest; the datum's height σ where
/// the figure gives one.
fn tilt_cell(t: Option<crate::report::DatumTiltReport>) -> String {
    t.map_or("–".into(), |t| {
        let height = t
            .sigma_height_m
            .map_or(String::new(), |h| format!(" (± {h:.3} m)"));
        format!(
            "{:.2} (gradient at {:.0}°) / {:.2}{height}",
            t.sigma_max_mm_per_m, t.loose_azimuth_deg, t.sigma_min_mm_per_m
        )
    })
}

/// Why an epoch the block did not tie to the reference epoch matters, and what to do.
pub(crate) fn not_co_registered_warning(name: &str) -> String {
    format!(
        "epoch {name}: not co-registered: no chain of epochs sharing {} tie points ties it to the \
         reference epoch, so its orientation rests on its own GNSS priors and control points \
         alone and its DEM and DoDs carry their errors; unchanged ground photographed in both \
         epochs or natural stable points measured in both (`[align] method = \"manual\"`) tie \
         it",
        crate::report::MIN_CO_REGISTERING_TIES
    )
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
