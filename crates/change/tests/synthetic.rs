//! Exact recovery on synthetic terrain of known shape: Nuth & Kääb shifts, volumes of analytic
//! shapes, M3C2 distances along known normals, ICP transforms; and the errors on bad input.

use proptest::prelude::*;
use timesift_change::ChangeError;
use timesift_change::dod::dem_of_difference;
use timesift_change::grid::{Dem, Grid};
use timesift_change::icp::{IcpModel, IcpOptions, icp};
use timesift_change::m3c2::{Aggregation, M3c2Params, m3c2, subsample_core_points};
use timesift_change::mask::Mask;
use timesift_change::nuth_kaab::{NuthKaabFit, NuthKaabOptions, nuth_kaab};
use timesift_change::volume::{VolumeOptions, volumes};
use timesift_core::rng::SeededRng;
use timesift_io::coords::Crs;
use timesift_io::geotiff::GeoTransform;
use timesift_io::wkt::parse_polygons;

fn grid(w: usize, h: usize, cell: f64) -> Grid {
    Grid {
        transform: GeoTransform {
            origin_x: 431_000.0,
            origin_y: 5_121_000.0,
            pixel_width: cell,
            pixel_height: -cell,
        },
        width: w,
        height: h,
        crs: Crs::Epsg(32632),
    }
}

/// Hilly terrain with every aspect: a sum of smooth bumps and waves (metres).
fn terrain(x: f64, y: f64) -> f64 {
    let (u, v) = (x - 431_000.0, y - 5_121_000.0);
    30.0 + 6.0 * (u / 23.0).sin() * (v / 31.0).cos()
        + 4.0 * ((u + 2.0 * v) / 47.0).sin()
        + 9.0 * (-((u - 120.0).powi(2) + (v + 150.0).powi(2)) / 3000.0).exp()
}

fn sample(grid: Grid, f: impl Fn(f64, f64) -> f64 + Sync) -> Dem {
    let values = (0..grid.len())
        .map(|i| {
            let (x, y) = grid.cell_center(i % grid.width, i / grid.width);
            f(x, y) as f32
        })
        .collect();
    Dem { grid, values }
}

/// The reference terrain and a copy displaced by `shift` (the copy shows at p the terrain at
/// p + shift), raised by `bias`, with a 40 m wide pit that is not stable ground.
fn shifted_pair(shift: [f64; 2], bias: f64, noise: f64, seed: u64) -> (Dem, Dem, Mask) {
    let g = grid(300, 300, 1.0);
    let reference = sample(g, terrain);
    let mut rng = SeededRng::new(seed);
    let pit = |x: f64, y: f64| {
        let r2 = (x - 431_200.0).powi(2) + (y - 5_120_800.0).powi(2);
        if r2 < 400.0 {
            -5.0 * (1.0 - r2 / 400.0)
        } else {
            0.0
        }
    };
    let mut moved = sample(g, |x, y| {
        terrain(x + shift[0], y + shift[1]) + bias + pit(x, y)
    });
    for v in &mut moved.values {
        *v += (noise * rng.normal()) as f32;
    }
    let stable = parse_polygons(
        "POLYGON ((431000 5121000, 431300 5121000, 431300 5120700, 431000 5120700, 431000 5121000), \
         (431170 5120830, 431230 5120830, 431230 5120770, 431170 5120770, 431170 5120830))",
    )
    .expect("wkt");
    (reference, moved, Mask::from_polygons(g, &stable))
}

#[test]
fn nuth_kaab_recovers_a_subpixel_shift_and_bias_on_stable_ground() {
    let (reference, moved, stable) = shifted_pair([1.37, -2.21], 0.8, 0.0, 1);
    for options in [
        NuthKaabOptions::default(),
        NuthKaabOptions {
            fit: NuthKaabFit::Weighted,
            ..Default::default()
        },
        NuthKaabOptions::xdem_like(),
    ] {
        check_recovery(&reference, &moved, &stable, &options);
    }
}

fn check_recovery(reference: &Dem, moved: &Dem, stable: &Mask, options: &NuthKaabOptions) {
    let r = nuth_kaab(reference, moved, Some(stable), options).expect("fit");
    assert!(r.converged);
    assert!((r.shift_east_m - 1.37).abs() < 0.01, "{r:?}");
    assert!((r.shift_north_m + 2.21).abs() < 0.01, "{r:?}");
    assert!((r.shift_z + 0.8).abs() < 0.005, "{}", r.shift_z);
    // Pixel convention: +east = +columns, +north = −rows.
    assert!((r.shift_px[0] - 1.37).abs() < 0.01 && (r.shift_px[1] - 2.21).abs() < 0.01);
    // The aligned DEM's difference is flat on stable ground, and the pit is still there.
    let dod = dem_of_difference(reference, &r.apply(moved)).expect("dod");
    let stable_dod = stable.onto(&dod.grid).expect("mask");
    let worst = dod
        .values
        .iter()
        .zip(&stable_dod.cells)
        .filter(|(v, s)| **s && !v.is_nan())
        .map(|(v, _)| v.abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 0.06, "{worst}");
    let (fc, fr) = dod.grid.continuous_index(431_200.0, 5_120_800.0);
    assert!(dod.get(fc.round() as usize, fr.round() as usize) < -4.5);
}

#[test]
fn nuth_kaab_error_under_noise_is_small() {
    // 5 cm height noise: the shift must stay within 0.05 px.
    let (reference, moved, stable) = shifted_pair([-0.63, 0.48], -0.2, 0.05, 7);
    let r = nuth_kaab(
        &reference,
        &moved,
        Some(&stable),
        &NuthKaabOptions::default(),
    )
    .expect("fit");
    assert!(
        (r.shift_east_m + 0.63).abs() < 0.05 && (r.shift_north_m - 0.48).abs() < 0.05,
        "{r:?}"
    );
    assert!((r.shift_z - 0.2).abs() < 0.01, "{}", r.shift_z);
}

#[test]
fn vertical_only_co_registration() {
    let (reference, moved, stable) = shifted_pair([0.0, 0.0], 1.25, 0.0, 3);
    let options = NuthKaabOptions {
        horizontal: false,
        ..Default::default()
    };
    let r = nuth_kaab(&reference, &moved, Some(&stable), &options).expect("fit");
    assert_eq!((r.shift_east_m, r.shift_north_m), (0.0, 0.0));
    assert!(r.iterations.is_empty());
    assert!((r.shift_z + 1.25).abs() < 1e-5, "{}", r.shift_z);
}

#[test]
fn nuth_kaab_bad_input() {
    let (reference, moved, stable) = shifted_pair([1.0, 1.0], 0.0, 0.0, 1);
    let empty = Mask {
        cells: vec![false; stable.cells.len()],
        ..stable.clone()
    };
    let e = nuth_kaab(
        &reference,
        &moved,
        Some(&empty),
        &NuthKaabOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e, ChangeError::EmptyStable(_)), "{e}");
    let mut other = moved.clone();
    other.grid.crs = Crs::Epsg(32633);
    let e = nuth_kaab(&reference, &other, None, &NuthKaabOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("EPSG:32632") && e.to_string().contains("EPSG:32633"),
        "{e}"
    );
    let mut far = moved.clone();
    far.grid.transform.origin_x += 10_000.0;
    let e = nuth_kaab(&reference, &far, None, &NuthKaabOptions::default()).unwrap_err();
    assert!(matches!(e, ChangeError::NoOverlap(_)), "{e}");
    // A flat plane fixes no horizontal shift.
    let flat = sample(reference.grid, |_, _| 12.0);
    let e = nuth_kaab(&flat, &flat, None, &NuthKaabOptions::default()).unwrap_err();
    assert!(matches!(e, ChangeError::NotEnoughData(_)), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed_0009), ..ProptestConfig::default() })]
    #[test]
    fn nuth_kaab_random_shifts(sx in -3.0f64..3.0, sy in -3.0f64..3.0, bias in -2.0f64..2.0) {
        let (reference, moved, stable) = shifted_pair([sx, sy], bias, 0.0, 11);
        let r = nuth_kaab(&reference, &moved, Some(&stable), &NuthKaabOptions::default()).expect("fit");
        prop_assert!((r.shift_east_m - sx).abs() < 0.02 && (r.shift_north_m - sy).abs() < 0.02, "{:?}", r);
        prop_assert!((r.shift_z + bias).abs() < 0.01);
    }
}

#[test]
fn volumes_of_an_excavation_and_a_mound() {
    // A paraboloid pit (depth 3 m, radius 20 m: V = π R² h / 2) and a cone mound (height 2 m,
    // radius 10 m: V = π R² h / 3), on a 0.25 m grid.
    let g = grid(400, 240, 0.25);
    let (pit_x, pit_y) = (431_030.0, 5_120_970.0);
    let (mound_x, mound_y) = (431_075.0, 5_120_970.0);
    let dod = sample(g, |x, y| {
        let r2 = (x - pit_x).powi(2) + (y - pit_y).powi(2);
        let rm = ((x - mound_x).powi(2) + (y - mound_y).powi(2)).sqrt();
        let pit = if r2 < 400.0 {
            -3.0 * (1.0 - r2 / 400.0)
        } else {
            0.0
        };
        let mound = if rm < 10.0 {
            2.0 * (1.0 - rm / 10.0)
        } else {
            0.0
        };
        pit + mound
    });
    let pit_volume = std::f64::consts::PI * 400.0 * 3.0 / 2.0;
    let mound_volume = std::f64::consts::PI * 100.0 * 2.0 / 3.0;
    let v = volumes(&dod, None, VolumeOptions::default()).expect("volumes");
    assert!(
        (v.cut - pit_volume).abs() < 0.005 * pit_volume,
        "{} vs {pit_volume}",
        v.cut
    );
    assert!(
        (v.fill - mound_volume).abs() < 0.005 * mound_volume,
        "{} vs {mound_volume}",
        v.fill
    );
    assert!((v.net - (mound_volume - pit_volume)).abs() < 0.005 * pit_volume);
    assert!((v.area - 100.0 * 60.0).abs() < 1e-6);
    // Over a polygon around the pit only.
    let region = Mask::from_polygons(
        g,
        &parse_polygons("POLYGON ((431005 5120995, 431055 5120995, 431055 5120945, 431005 5120945, 431005 5120995))")
            .expect("wkt"),
    );
    let v = volumes(&dod, Some(&region), VolumeOptions::default()).expect("volumes");
    assert!(v.fill == 0.0 && (v.cut - pit_volume).abs() < 0.005 * pit_volume);
    // Uncertainty: random part σ·A·√n, systematic part σ·A·n.
    let options = VolumeOptions {
        threshold: 0.0,
        sigma_random: 0.1,
        sigma_systematic: 0.02,
        correlation: None,
    };
    let v = volumes(&dod, Some(&region), options).expect("volumes");
    let a = 0.25 * 0.25;
    let n = v.cells as f64;
    assert!((v.sigma_random - 0.1 * a * n.sqrt()).abs() < 1e-9);
    assert!((v.sigma_systematic - 0.02 * a * n).abs() < 1e-9);
    assert!((v.sigma_net - v.sigma_random.hypot(v.sigma_systematic)).abs() < 1e-12);
}

#[test]
fn volume_bad_input() {
    let g = grid(10, 10, 1.0);
    let dod = sample(g, |_, _| 1.0);
    let none = Mask {
        grid: g,
        cells: vec![false; 100],
    };
    assert!(matches!(
        volumes(&dod, Some(&none), VolumeOptions::default()),
        Err(ChangeError::EmptyStable(_))
    ));
    let bad = VolumeOptions {
        threshold: -1.0,
        ..Default::default()
    };
    let e = volumes(&dod, None, bad).unwrap_err();
    assert!(e.to_string().contains("threshold"), "{e}");
}

/// Points on a tilted wavy surface, 0.2 m apart.
fn surface_points(n: usize, offset_along_normal: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut a = Vec::new();
    let mut b = Vec::new();
    // Plane z = 0.3 x − 0.2 y: unit normal (−0.3, 0.2, 1)/|·|.
    let norm = (0.09f64 + 0.04 + 1.0).sqrt();
    let normal = [-0.3 / norm, 0.2 / norm, 1.0 / norm];
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 * 0.2 + 0.013 * (j % 3) as f64, j as f64 * 0.2);
            let p = [500_000.0 + x, 4_000_000.0 + y, 100.0 + 0.3 * x - 0.2 * y];
            a.push(p);
            b.push([
                p[0] + offset_along_normal * normal[0],
                p[1] + offset_along_normal * normal[1],
                p[2] + offset_along_normal * normal[2],
            ]);
        }
    }
    (a, b)
}

#[test]
fn m3c2_measures_a_shift_along_the_normal_exactly() {
    let (a, b) = surface_points(100, 0.137);
    let core = subsample_core_points(&a, 2.0).expect("core");
    assert!(core.len() > 50);
    for aggregation in [Aggregation::Mean, Aggregation::Median] {
        let params = M3c2Params {
            normal_radii: vec![0.8, 1.5],
            cylinder_radius: 0.5,
            max_depth: 1.0,
            registration_error: 0.01,
            aggregation,
            orientation: [0.0, 0.0, 1.0],
        };
        let out = m3c2(&a, &b, &core, &params).expect("m3c2");
        let mut defined = 0;
        for (p, c) in out.iter().zip(&core) {
            let inside =
                c[0] > 500_002.0 && c[0] < 500_017.0 && c[1] > 4_000_002.0 && c[1] < 4_000_017.0;
            if !inside {
                continue;
            }
            defined += 1;
            assert!((p.distance - 0.137).abs() < 1e-9, "{aggregation:?} {p:?}");
            // No spread on a plane: the LoD is the registration term.
            assert!((p.lod95 - 1.96 * 0.01).abs() < 1e-6, "{p:?}");
            assert!(p.significant());
            assert!(p.normal[2] > 0.0 && (p.normal[0] * (1.13f64).sqrt() + 0.3).abs() < 1e-9);
        }
        assert!(defined > 40);
    }
    // A cylinder that misses the second cloud gives NaN, not a number.
    let params = M3c2Params {
        max_depth: 0.1,
        cylinder_radius: 0.05,
        ..M3c2Params::default()
    };
    let out = m3c2(&a, &b, &core, &params).expect("m3c2");
    assert!(out.iter().all(|p| p.distance.is_nan()));
}

#[test]
fn m3c2_lod_follows_the_noise() {
    // Independent 2 cm noise on both clouds: the LoD95 is 1.96·σ·sqrt(1/n1 + 1/n2) on average.
    let (mut a, mut b) = surface_points(120, 0.05);
    let mut rng = SeededRng::new(5);
    let sigma = 0.02;
    for p in a.iter_mut().chain(b.iter_mut()) {
        p[2] += sigma * rng.normal();
    }
    let core = subsample_core_points(&a, 1.5).expect("core");
    let params = M3c2Params {
        normal_radii: vec![1.5],
        cylinder_radius: 0.75,
        max_depth: 1.0,
        ..M3c2Params::default()
    };
    let out = m3c2(&a, &b, &core, &params).expect("m3c2");
    let inner: Vec<_> = out
        .iter()
        .filter(|p| p.count[0] > 30 && p.count[1] > 30)
        .collect();
    assert!(inner.len() > 80);
    let normal_z = 1.0 / (1.13f64).sqrt();
    let mean: f64 = inner.iter().map(|p| p.distance).sum::<f64>() / inner.len() as f64;
    assert!((mean - 0.05).abs() < 0.003, "{mean}");
    // Vertical noise σ seen along the normal is σ·n_z.
    let predicted: f64 = inner
        .iter()
        .map(|p| {
            1.96 * sigma * normal_z * (1.0 / p.count[0] as f64 + 1.0 / p.count[1] as f64).sqrt()
        })
        .sum::<f64>()
        / inner.len() as f64;
    let lod: f64 = inner.iter().map(|p| p.lod95).sum::<f64>() / inner.len() as f64;
    assert!((lod / predicted - 1.0).abs() < 0.1, "{lod} vs {predicted}");
}

#[test]
fn m3c2_bad_parameters() {
    let (a, b) = surface_points(10, 0.1);
    for params in [
        M3c2Params {
            normal_radii: vec![],
            ..M3c2Params::default()
        },
        M3c2Params {
            cylinder_radius: 0.0,
            ..M3c2Params::default()
        },
        M3c2Params {
            max_depth: f64::NAN,
            ..M3c2Params::default()
        },
        M3c2Params {
            registration_error: -1.0,
            ..M3c2Params::default()
        },
    ] {
        assert!(matches!(
            m3c2(&a, &b, &a, &params),
            Err(ChangeError::InvalidParameter { .. })
        ));
    }
    assert!(m3c2(&[], &b, &a, &M3c2Params::default()).is_err());
}

/// A rigid transform about `centre`: rotation by `angle_deg` about `axis`, then `t`.
fn rigid(
    points: &[[f64; 3]],
    axis: [f64; 3],
    angle_deg: f64,
    t: [f64; 3],
    centre: [f64; 3],
) -> Vec<[f64; 3]> {
    let r = nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(nalgebra::Vector3::from(axis)),
        angle_deg.to_radians(),
    );
    let c = nalgebra::Vector3::from(centre);
    points
        .iter()
        .map(|p| {
            let q = r * (nalgebra::Vector3::from(*p) - c) + c + nalgebra::Vector3::from(t);
            [q.x, q.y, q.z]
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 8, rng_seed: proptest::test_runner::RngSeed::Fixed(0x1c9), ..ProptestConfig::default() })]
    #[test]
    fn icp_recovers_random_small_transforms(
        ax in -1.0f64..1.0, ay in -1.0f64..1.0, angle in -1.0f64..1.0,
        tx in -0.5f64..0.5, ty in -0.5f64..0.5, tz in -0.5f64..0.5,
    ) {
        let g = grid(120, 120, 1.0);
        let target = sample(g, terrain).to_points();
        let centre = target[target.len() / 2];
        let source = rigid(&target, [ax, ay, 1.0], angle, [tx, ty, tz], centre);
        let r = icp(&source, &target, &IcpOptions::default()).expect("icp");
        for (s, t) in source.iter().zip(&target).step_by(97) {
            let q = r.transform(s);
            let err = ((q[0] - t[0]).powi(2) + (q[1] - t[1]).powi(2) + (q[2] - t[2]).powi(2)).sqrt();
            prop_assert!(err < 1e-4, "{err} {r:?}");
        }
    }
}

#[test]
fn icp_with_scale_and_its_errors() {
    let g = grid(100, 100, 1.0);
    let target = sample(g, terrain).to_points();
    let centre = target[5050];
    let source: Vec<[f64; 3]> = rigid(&target, [0.2, -0.4, 1.0], 0.4, [0.3, 0.1, -0.2], centre)
        .iter()
        .map(|p| {
            [
                centre[0] + 1.002 * (p[0] - centre[0]),
                centre[1] + 1.002 * (p[1] - centre[1]),
                centre[2] + 1.002 * (p[2] - centre[2]),
            ]
        })
        .collect();
    let options = IcpOptions {
        model: IcpModel::Similarity,
        ..Default::default()
    };
    let r = icp(&source, &target, &options).expect("icp");
    assert!((r.scale - 1.0 / 1.002).abs() < 1e-7, "{}", r.scale);
    // A plane does not fix the in-plane translation.
    let plane = sample(g, |x, _| 0.1 * (x - 431_000.0)).to_points();
    let e = icp(&plane, &plane, &IcpOptions::default()).unwrap_err();
    assert!(matches!(e, ChangeError::Degenerate(_)), "{e}");
    let e = icp(&target[..5], &target, &IcpOptions::default()).unwrap_err();
    assert!(matches!(e, ChangeError::NotEnoughData(_)), "{e}");
    let e = icp(
        &source,
        &target,
        &IcpOptions {
            overlap: 0.0,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("overlap"), "{e}");
}

#[test]
fn m3c2_search_strategies_agree() {
    // Dense core points take the tile-gathering path; one core point at a time takes the per-point
    // slab path. Same membership rules, so the same numbers.
    let (mut a, mut b) = surface_points(80, 0.2);
    let mut rng = SeededRng::new(9);
    for p in a.iter_mut().chain(b.iter_mut()) {
        p[0] += 0.03 * rng.normal();
        p[2] += 0.05 * rng.normal();
    }
    let core = subsample_core_points(&a, 0.4).expect("core");
    for aggregation in [Aggregation::Mean, Aggregation::Median] {
        let params = M3c2Params {
            normal_radii: vec![0.6, 1.2],
            cylinder_radius: 0.3,
            max_depth: 1.0,
            aggregation,
            ..M3c2Params::default()
        };
        let together = m3c2(&a, &b, &core, &params).expect("m3c2");
        let mut compared = 0;
        for (i, c) in core.iter().enumerate().step_by(7) {
            let alone = m3c2(&a, &b, std::slice::from_ref(c), &params).expect("m3c2")[0];
            let t = together[i];
            assert_eq!(t.count, alone.count, "{i}");
            assert_eq!(t.distance.is_nan(), alone.distance.is_nan());
            if t.distance.is_finite() {
                assert!(
                    (t.distance - alone.distance).abs() < 1e-12,
                    "{t:?} {alone:?}"
                );
                assert!(
                    (t.lod95 - alone.lod95).abs() < 1e-12
                        || (t.lod95.is_nan() && alone.lod95.is_nan())
                );
                compared += 1;
            }
        }
        assert!(compared > 100, "{compared}");
    }
}

#[test]
fn south_up_or_degenerate_grids_are_refused_and_tiny_dems_shift_vertically() {
    use timesift_io::geotiff::{GeoRaster, GeoReference};
    let raster = |pw: f64, ph: f64, w: usize, h: usize, z: f32| GeoRaster {
        width: w,
        height: h,
        bands: 1,
        data: vec![z; w * h],
        georef: GeoReference {
            transform: GeoTransform {
                origin_x: 0.0,
                origin_y: 0.0,
                pixel_width: pw,
                pixel_height: ph,
            },
            crs: Crs::Epsg(32632),
            nodata: None,
            pixel_is_point: false,
        },
    };
    for (pw, ph) in [(1.0, 1.0), (-1.0, -1.0), (0.0, -1.0)] {
        let e = Dem::from_raster(raster(pw, ph, 4, 4, 1.0), None).unwrap_err();
        assert!(e.to_string().contains("north-up"), "{e}");
    }
    // 2 × 2 DEMs have no interior slope, but a vertical shift needs none.
    let a = Dem::from_raster(raster(1.0, -1.0, 2, 2, 10.0), None).expect("dem");
    let b = Dem::from_raster(raster(1.0, -1.0, 2, 2, 10.4), None).expect("dem");
    let options = NuthKaabOptions {
        horizontal: false,
        ..Default::default()
    };
    let r = nuth_kaab(&a, &b, None, &options).expect("vertical");
    assert!((r.shift_z + 0.4).abs() < 1e-5, "{}", r.shift_z);
}
