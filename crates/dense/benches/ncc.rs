//! Criterion bench of PatchMatch's innermost work: the cost of one plane hypothesis against one
//! source view (plane-induced homography, then the bilateral-weighted NCC over the sparse
//! window), with the default window (radius 5, step 2). Every pixel of every iteration
//! evaluates a few dozen of these, so the dense stage's time follows this figure.

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use timesift_core::SeededRng;
use timesift_dense::patchmatch::cost::{
    RefCamera, RefWindow, SourceView, WindowShape, homography, ncc_cost,
};
use timesift_dense::{Mask, Plane, WorkingCamera};

/// A textured plane: smooth noise plus fine grain, intensities 0–1.
fn texture(width: usize, height: usize, rng: &mut SeededRng) -> Plane {
    let mut plane = Plane::filled(width, height, 0.0);
    for j in 0..height {
        for i in 0..width {
            let (x, y) = (i as f32, j as f32);
            let smooth = 0.5 + 0.2 * (0.21 * x).sin() * (0.17 * y).cos();
            plane.data[j * width + i] = smooth + 0.25 * rng.uniform() as f32;
        }
    }
    plane
}

fn benches(c: &mut Criterion) {
    let (width, height) = (640, 480);
    let mut rng = SeededRng::new(7);
    let reference = texture(width, height, &mut rng);
    let source = texture(width, height, &mut rng);
    let mask = Mask::all(width, height);
    let camera = WorkingCamera {
        width,
        height,
        f: 500.0,
        cx: 320.0,
        cy: 240.0,
    };
    // The source 2 m to the side of the reference, both 30 m above the ground: a nadir pair.
    let src = SourceView {
        grey: &source,
        mask: &mask,
        camera,
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        t: [-2.0, 0.0, 0.0],
        depth: None,
    };
    let k_ref = RefCamera::of(&camera);
    let shape = WindowShape::new(5, 2, 5.0, 0.1).expect("window");
    let mut window = RefWindow::new(&shape);
    // Hypotheses: pixels away from the border, planes tilted up to ~30° at 25–35 m.
    let hypotheses: Vec<(usize, usize, [f32; 3], f32)> = (0..4096)
        .map(|_| {
            let i = 20 + (rng.uniform() * (width - 40) as f64) as usize;
            let j = 20 + (rng.uniform() * (height - 40) as f64) as usize;
            let (a, b) = (
                0.5 * (rng.uniform() as f32 - 0.5),
                0.5 * (rng.uniform() as f32 - 0.5),
            );
            let norm = (a * a + b * b + 1.0).sqrt();
            let n = [a / norm, b / norm, -1.0 / norm];
            let w = 25.0 + 10.0 * rng.uniform() as f32;
            (i, j, n, w)
        })
        .collect();
    c.bench_function("ncc_cost of 4096 hypotheses (radius 5, step 2)", |bench| {
        bench.iter(|| {
            let mut sum = 0.0f32;
            for &(i, j, n, w) in &hypotheses {
                if window.fill(&shape, &reference, i, j) {
                    let h = homography(&src, &k_ref, &n, w);
                    sum += ncc_cost(&shape, &window, &src, &h, i as f32 + 0.5, j as f32 + 0.5);
                }
            }
            black_box(sum)
        })
    });
    // As PatchMatch calls it: the reference window filled once per pixel, then a few dozen
    // hypotheses and sources scored against it (here 16 planes at each of 256 pixels).
    let pixels: Vec<(usize, usize, RefWindow)> = hypotheses
        .iter()
        .take(256)
        .filter_map(|&(i, j, _, _)| {
            let mut window = RefWindow::new(&shape);
            window
                .fill(&shape, &reference, i, j)
                .then_some((i, j, window))
        })
        .collect();
    let planes: Vec<[f32; 9]> = hypotheses
        .iter()
        .take(16)
        .map(|&(_, _, n, w)| homography(&src, &k_ref, &n, w))
        .collect();
    c.bench_function("ncc_cost alone, 16 planes at 256 pixels", |bench| {
        bench.iter(|| {
            let mut sum = 0.0f32;
            for (i, j, window) in &pixels {
                for h in &planes {
                    sum += ncc_cost(&shape, window, &src, h, *i as f32 + 0.5, *j as f32 + 0.5);
                }
            }
            black_box(sum)
        })
    });
}

criterion_group!(dense, benches);
criterion_main!(dense);
