//! The report stage on a project where only the orientation report exists: every section is on
//! the page, the missing products say what is missing instead of failing the stage, and the
//! warnings about the orientation reach the summary. A stats.json that cannot be read is a
//! warning naming the file, not a silent gap.

use std::collections::BTreeMap;
use std::path::Path;

use crate::common::timesift;
use timesift::report::{
    AlignReport, EpochOrientation, PointResidual, PointResiduals, Rmse, write_json,
};

fn project(dir: &Path) {
    for epoch in ["2018", "2019"] {
        let folder = dir.join("images").join(epoch);
        std::fs::create_dir_all(&folder).expect("dir");
        for i in 0..2 {
            image::GrayImage::from_fn(16, 12, |x, y| image::Luma([(x * 10 + y + i) as u8]))
                .save(folder.join(format!("img{i}.png")))
                .expect("png");
        }
    }
    std::fs::write(
        dir.join("project.toml"),
        "crs = \"local\"\n[[epoch]]\nname = \"2018\"\n[[epoch]]\nname = \"2019\"\n",
    )
    .expect("toml");
    // One check point in 2018: 120 mm off in height, of which its two markers alone allow 87.
    let check = PointResiduals {
        points: vec![PointResidual {
            name: "CHK1".into(),
            images: 2,
            de: Some(0.01),
            dn: Some(-0.02),
            dh: Some(0.12),
            markers_sigma: Some([0.011, 0.013, 0.087]),
        }],
        rmse: Some(Rmse {
            de: 0.01,
            dn: 0.02,
            dh: 0.12,
            n: 1,
        }),
        markers_rmse: Some(Rmse {
            de: 0.011,
            dn: 0.013,
            dh: 0.087,
            n: 1,
        }),
    };
    let term = |value, sigma| timesift::report::Term { value, sigma };
    // The later epoch's tie points against the reference epoch's surface: a tilt of 1.2 ± 0.1
    // mm/m (significant), the rest within their σ.
    let surface = timesift::report::SurfaceFitReport {
        points_compared: 900,
        points_kept: 800,
        points_held: 400,
        sigma_m: 0.085,
        offset_m: term(-0.012, 0.01),
        slope_east_mm_per_m: term(-1.2, 0.1),
        slope_north_mm_per_m: term(0.05, 0.1),
        tilt_mm_per_m: term(1.2, 0.1),
        dome_mm_at_100m: Some(term(0.4, 0.5)),
        height_scale_mm_per_m: None,
    };
    let epoch = |oriented, check_points, surface_fit| EpochOrientation {
        images_given: 2,
        images_oriented: oriented,
        rms_reprojection_px: Some(0.4),
        observations: 100,
        tie_points: 50,
        inter_epoch_tie_points: 10,
        control_points: PointResiduals::default(),
        check_points,
        gnss_offset: None,
        datum_tilt: None,
        block_tilt: Some(timesift::report::DatumTiltReport {
            sigma_max_mm_per_m: 0.83,
            sigma_min_mm_per_m: 0.27,
            loose_azimuth_deg: 161.0,
            sigma_height_m: None,
        }),
        surface_fit,
    };
    let report = AlignReport {
        method: timesift_align::Method::Timesift,
        datum: "Local".into(),
        images_given: 4,
        images_oriented: 3,
        rms_reprojection_px: Some(0.4),
        tie_points: 90,
        mapper: Some("incremental".into()),
        inter_epoch_ties_split_as_moved: 0,
        inter_epoch_ties_split_off_stable: 0,
        inter_epoch_ties_joined: 0,
        inter_epoch_ties_guided: 0,
        changed_regions: 0,
        surface_heights: 400,
        reference_dem: None,
        observation_bound_px: Some(2.0),
        group_noise: Vec::new(),
        components_dropped: 0,
        gnss_priors_rejected: 0,
        focal_length_held: vec![false],
        cameras: Vec::new(),
        seconds: 1.0,
        colmap_terms_dropped: Vec::new(),
        epochs: BTreeMap::from([
            ("2018".into(), epoch(2, check, None)),
            (
                "2019".into(),
                epoch(1, PointResiduals::default(), Some(surface)),
            ),
        ]),
        epoch_pairs: Vec::new(),
        not_co_registered: Vec::new(),
        control_points_rejected: Vec::new(),
    };
    write_json(&dir.join("out/report.json"), &report).expect("report.json");
}

#[test]
fn a_report_of_the_orientation_alone_has_every_section_and_says_what_is_missing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    project(dir);
    let d = dir.to_str().expect("utf-8");
    let (ok, _, err) = timesift(&["run", d, "--from", "report", "--to", "report"]);
    assert!(ok, "{err}");
    assert!(err.contains("2 warnings"), "{err}");
    let html = std::fs::read_to_string(dir.join("out/report.html")).expect("html");
    for id in timesift::html::SECTIONS {
        assert!(html.contains(&format!("<section id=\"{id}\">")), "{id}");
    }
    assert!(html.contains("block tilt σ mm/m") && html.contains("0.83 (gradient at 161°) / 0.27"));
    assert!(html.contains("epoch 2019: 1 of 2 images could not be oriented"));
    // The surface fit: its table, the significant tilt in bold and warned about, a height
    // scale not fitted.
    assert!(
        html.contains("400 of them held to it by height observations"),
        "{html}"
    );
    assert!(html.contains("<td>400 / 800 / 900</td>"), "{html}");
    assert!(html.contains("<b>1.20 ± 0.10</b>"), "{html}");
    assert!(
        html.contains("<td>0.4 ± 0.5</td>") && html.contains("<td>–</td>"),
        "{html}"
    );
    assert!(
        html.contains("epoch 2019: its tie points miss the reference epoch&#39;s surface by a tilt of 1.20 mm/m"),
        "{html}"
    );
    assert!(html.contains("out/tiepoints.ply is missing"));
    assert!(html.contains("Not computed (change stage)"));
    assert!(!html.contains("src=\"http"), "no network resource");
    // The check point's height error beside what its markers alone allow, and their RMSE.
    assert!(html.contains("σH of its markers mm"), "{html}");
    assert!(html.contains("<td>120.0</td><td>87.0</td>"), "{html}");
    assert!(html.contains("check RMSE from the markers alone"), "{html}");

    // A stats.json that is not a DEM comparison: named in a warning.
    let stats = dir.join("out/change/2018__2019/stats.json");
    std::fs::create_dir_all(stats.parent().expect("parent")).expect("dir");
    std::fs::write(&stats, "{\"a\": 1}").expect("stats");
    let (ok, _, err) = timesift(&["run", d, "--from", "report", "--to", "report"]);
    assert!(ok, "{err}");
    let html = std::fs::read_to_string(dir.join("out/report.html")).expect("html");
    assert!(
        html.contains("stats.json") && html.contains("not the expected report"),
        "{html}"
    );
}
