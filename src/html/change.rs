//! The report's change section: per epoch pair the DoD's statistics, stable-area plane, LoD,
//! volumes and figures, and the M3C2 comparison of the dense clouds.

use super::*;

pub(super) fn volume_row(label: &str, v: &timesift_change::volume::Volumes) -> Vec<String> {
    vec![
        esc(label),
        num(Some(v.cut), 1),
        num(Some(v.fill), 1),
        format!("{} ± {}", num(Some(v.net), 1), num(Some(v.sigma_net), 1)),
        num(Some(v.area), 0),
        v.changed_cells.to_string(),
    ]
}

pub(super) fn change_section(
    project: &Project,
    align: &AlignReport,
    warnings: &mut Vec<String>,
) -> String {
    let layout = project.layout();
    let mut s = String::from(
        "<p>Later minus earlier: red where the ground rose, blue where it lowered; cells within \
         the 95 % level of detection (LoD95) are grey. Statistics over the stable areas measure \
         how well the epochs are co-registered: a median and a plane near zero are what the \
         Time-SIFT block should deliver without any co-registration step.</p>",
    );
    if crate::stages::change_stable_areas(project).is_some_and(|p| p == layout.stable_found()) {
        s.push_str(
            "<p>No stable areas were given (<code>stable.csv</code>): the stable areas here are \
             the ground the align stage found unchanged, where the later epochs' tie points met \
             the reference epoch's surface (<code>out/stable_found.tif</code>, 5 m cells). \
             Ground that changed by less than a tie point's scatter passes as stable; give \
             <code>stable.csv</code> where you know better.</p>",
        );
    }
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
        let predicted = align
            .epoch_pairs
            .iter()
            .find(|p| p.epochs[0] == a && p.epochs[1] == b)
            .and_then(|p| p.dod_tilt);
        s.push_str(&dod_statistics(&a, &b, &dem, predicted, warnings));
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
fn dod_statistics(
    a: &str,
    b: &str,
    dem: &DemReport,
    predicted: Option<crate::report::DatumTiltReport>,
    warnings: &mut Vec<String>,
) -> String {
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
            if let Some(p) = predicted {
                let sigmas = t.slope * 1000.0 / p.sigma_max_mm_per_m;
                let _ = write!(
                    s,
                    "<p>The block allows this DoD a tilt of σ = {} mm/m (loosest, gradient at \
                     {}° from east; firmest {} mm/m), from its covariance: what the \
                     inter-epoch ties, GNSS and control hold. The stable areas tilt by {} σ.</p>",
                    num(Some(p.sigma_max_mm_per_m), 2),
                    num(Some(p.loose_azimuth_deg), 0),
                    num(Some(p.sigma_min_mm_per_m), 2),
                    num(Some(sigmas), 1)
                );
                if sigmas > 3.0 {
                    warnings.push(format!(
                        "{a} → {b}: the stable areas tilt by {:.2} mm/m, {sigmas:.1} times \
                         the σ the block predicts ({:.2} mm/m): a fault the adjustment does \
                         not model (ground that moved taken as stable, a camera model that \
                         bends the block), not noise",
                        t.slope * 1000.0,
                        p.sigma_max_mm_per_m
                    ));
                }
            }
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

pub(super) fn stat_row(label: &str, st: &timesift_change::stats::Statistics) -> Vec<String> {
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
