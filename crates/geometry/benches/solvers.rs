//! Time per call of every minimal solver, and RANSAC on 2,000 correspondences with 50 % outliers.

#[path = "../tests/common/mod.rs"]
mod common;

use std::hint::black_box;

use common::*;
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Vector2, Vector3};
use timesift_core::{CameraModel, Pose, SeededRng};
use timesift_geometry::essential::{EssentialEstimator, eight_point_essential, five_point};
use timesift_geometry::fundamental::{FundamentalEstimator, eight_point, seven_point};
use timesift_geometry::homography::{HomographyEstimator, homography_dlt};
use timesift_geometry::p3p::p3p;
use timesift_geometry::pnp::{AbsolutePoseEstimator, dlt_pnp};
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::similarity::{TransformKind, umeyama};
use timesift_geometry::triangulation::triangulate_dlt;

fn minimal_solvers(c: &mut Criterion) {
    let mut rng = SeededRng::new(1);
    let s = two_view(&mut rng, 100, false);
    let (p1, p2) = (pixels(&s.x1), pixels(&s.x2));
    let planar = two_view(&mut rng, 4, true);
    let (h1, h2) = (pixels(&planar.x1), pixels(&planar.x2));
    let cam = camera();
    let abs = absolute_scene(&mut rng, &cam, 50, false);
    let src: Vec<Vector3<f64>> = s.points.clone();
    let dst: Vec<Vector3<f64>> = src
        .iter()
        .map(|p| p * 2.0 + Vector3::new(1.0, 2.0, 3.0))
        .collect();
    let views: Vec<(Pose, Vector3<f64>)> =
        vec![(Pose::identity(), s.x1[0]), (s.cam2_from_cam1, s.x2[0])];

    let mut g = c.benchmark_group("minimal");
    g.bench_function("five_point", |b| {
        b.iter(|| five_point(black_box(&s.x1[..5]), black_box(&s.x2[..5])))
    });
    g.bench_function("seven_point", |b| {
        b.iter(|| seven_point(black_box(&p1[..7]), black_box(&p2[..7])))
    });
    g.bench_function("homography_4pt", |b| {
        b.iter(|| homography_dlt(black_box(&h1), black_box(&h2), None))
    });
    g.bench_function("p3p_lambda_twist", |b| {
        b.iter(|| p3p(black_box(&abs.rays[..3]), black_box(&abs.world[..3])))
    });
    g.bench_function("umeyama_3pt", |b| {
        b.iter(|| {
            umeyama(
                black_box(&src[..3]),
                black_box(&dst[..3]),
                None,
                TransformKind::Similarity,
            )
        })
    });
    g.finish();

    let mut g = c.benchmark_group("nonminimal");
    g.bench_function("eight_point_fundamental_100", |b| {
        b.iter(|| eight_point(black_box(&p1), black_box(&p2), None))
    });
    g.bench_function("eight_point_essential_100", |b| {
        b.iter(|| eight_point_essential(black_box(&s.x1), black_box(&s.x2), None))
    });
    g.bench_function("dlt_pnp_50", |b| {
        b.iter(|| dlt_pnp(black_box(&abs.rays), black_box(&abs.world)))
    });
    g.bench_function("triangulate_dlt_2view", |b| {
        b.iter(|| triangulate_dlt(black_box(&views)))
    });
    g.finish();
}

/// 2,000 correspondences, half of them uniform outliers.
fn contaminated(seed: u64, planar: bool) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let mut rng = SeededRng::new(seed);
    let s = two_view(&mut rng, 1000, planar);
    let mut a = noisy(&mut rng, &s.x1, 0.5);
    let mut b = noisy(&mut rng, &s.x2, 0.5);
    for _ in 0..1000 {
        a.push(Vector3::new(
            rng.uniform_range(-0.8, 0.8),
            rng.uniform_range(-0.6, 0.6),
            1.0,
        ));
        b.push(Vector3::new(
            rng.uniform_range(-0.8, 0.8),
            rng.uniform_range(-0.6, 0.6),
            1.0,
        ));
    }
    (a, b)
}

fn robust(c: &mut Criterion) {
    let options = RansacOptions {
        max_error: 2.0,
        confidence: 0.999,
        ..RansacOptions::default()
    };
    let (a, b) = contaminated(2, false);
    let (pa, pb) = (pixels(&a), pixels(&b));
    let (ha, hb) = contaminated(3, true);
    let (pha, phb) = (pixels(&ha), pixels(&hb));
    let cam = camera();
    let mut rng = SeededRng::new(4);
    let abs = absolute_scene(&mut rng, &cam, 2000, false);
    let px: Vec<Vector2<f64>> = abs
        .pixels
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if i % 2 == 0 {
                p + Vector2::new(rng.normal(), rng.normal()) * 0.5
            } else {
                Vector2::new(
                    rng.uniform_range(0.0, 1600.0),
                    rng.uniform_range(0.0, 1200.0),
                )
            }
        })
        .collect();
    let rays: Vec<_> = px.iter().map(|p| cam.unproject(p).unwrap()).collect();

    let mut g = c.benchmark_group("ransac_2000_half_outliers");
    g.sample_size(20);
    g.bench_function("essential", |bch| {
        bch.iter(|| {
            ransac(
                &EssentialEstimator {
                    x1: &a,
                    x2: &b,
                    focal_px: FOCAL,
                },
                &options,
            )
        })
    });
    g.bench_function("fundamental", |bch| {
        bch.iter(|| ransac(&FundamentalEstimator { p1: &pa, p2: &pb }, &options))
    });
    g.bench_function("homography", |bch| {
        bch.iter(|| ransac(&HomographyEstimator { p1: &pha, p2: &phb }, &options))
    });
    g.bench_function("absolute_pose", |bch| {
        bch.iter(|| {
            ransac(
                &AbsolutePoseEstimator {
                    camera: &cam,
                    pixels: &px,
                    rays: &rays,
                    world: &abs.world,
                },
                &options,
            )
        })
    });
    g.finish();
}

// No plots: criterion's plotters charts need system fonts, which the workspace's plotters build
// (ab_glyph, no font discovery) does not provide.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = minimal_solvers, robust
}
criterion_main!(benches);
