//! Criterion benches of the change stage on real data: M3C2 between two sandpyper `mar` DSM clouds,
//! Nuth & Kääb on the demcompare SRTM pair, ICP on a sandpyper cloud.

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use timesift_change::grid::Dem;
use timesift_change::icp::{IcpOptions, icp};
use timesift_change::m3c2::{M3c2Params, m3c2, subsample_core_points};
use timesift_change::nuth_kaab::{NuthKaabOptions, nuth_kaab};
use timesift_io::geotiff::read_f32;

fn shared(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(path)
}

fn dem(path: &str, extra_nodata: Option<f64>) -> Dem {
    let raster = read_f32(&shared(path)).unwrap_or_else(|e| panic!("{path}: {e}"));
    Dem::from_raster(raster, extra_nodata).expect("dem")
}

fn benches(c: &mut Criterion) {
    let e1 = dem(
        "sandpyper-mar/dsm/mar_20180601_dsm_resampled_1m.tif",
        Some(-10000.0),
    )
    .to_points();
    let e2 = dem(
        "sandpyper-mar/dsm/mar_20180621_dsm_resampled_1m.tif",
        Some(-10000.0),
    )
    .to_points();
    let core = subsample_core_points(&e1, 1.0).expect("core");
    let params = M3c2Params {
        normal_radii: vec![2.5],
        cylinder_radius: 1.5,
        max_depth: 4.5,
        registration_error: 0.05,
        ..M3c2Params::default()
    };
    c.bench_function("m3c2 sandpyper (trees included)", |b| {
        b.iter(|| m3c2(&e1, &e2, &core, &params).expect("m3c2"))
    });

    let reference = dem("demcompare-srtm/input/srtm_ref.tif", None);
    let secondary = dem("demcompare-srtm/input/srtm_blurred_and_shifted.tif", None);
    let mut group = c.benchmark_group("slow");
    group.sample_size(10);
    group.bench_function("nuth_kaab srtm 1000x1000", |b| {
        b.iter(|| {
            nuth_kaab(&reference, &secondary, None, &NuthKaabOptions::default()).expect("fit")
        })
    });
    let moved: Vec<[f64; 3]> = e1
        .iter()
        .map(|p| [p[0] + 0.3, p[1] - 0.2, p[2] + 0.1])
        .collect();
    group.bench_function("icp sandpyper", |b| {
        b.iter(|| icp(&moved, &e1, &IcpOptions::default()).expect("icp"))
    });
    group.finish();
}

// No plots: criterion's plotters charts need system fonts, which the workspace's plotters build
// (ab_glyph, no font discovery) does not provide.
criterion_group! {
    name = change;
    config = Criterion::default().without_plots();
    targets = benches
}
criterion_main!(change);
