//! Heightfield terrain: the rendered mesh and `height_at` describe the same surface, and a textured
//! terrain renders with detail everywhere.

use nalgebra::Vector3;
use timesift_core::{BrownCamera, Pose, SeededRng};
use timesift_synth::noise::Noise;
use timesift_synth::render::{Material, RenderOptions, Scene, render};
use timesift_synth::terrain::Heightfield;

fn terrain() -> Heightfield {
    let noise = Noise::new(5);
    Heightfield::from_fn((1000.0, 2000.0), 0.5, 121, 101, |x, y| {
        50.0 + 6.0 * noise.fbm(x, y, 0.0, 25.0, 5, 0.5)
    })
}

#[test]
fn rays_hit_the_surface_height_at_describes() {
    let field = terrain();
    let (vertices, triangles) = field.mesh();
    assert_eq!(triangles.len(), 2 * 120 * 100);
    let scene = Scene::new(
        &vertices,
        &triangles,
        vec![0; triangles.len()],
        vec![Material::Flat(0.5)],
    )
    .expect("scene");
    let mut rng = SeededRng::new(1);
    for _ in 0..500 {
        // Origins 50 m above the surface: rays land within 16 m of them, inside the grid.
        let (x, y) = (
            rng.uniform_range(1018.0, 1042.0),
            rng.uniform_range(2017.0, 2033.0),
        );
        // Oblique rays too: the hit must lie on the surface whatever the direction.
        let dir = Vector3::new(
            rng.uniform_range(-0.3, 0.3),
            rng.uniform_range(-0.3, 0.3),
            -1.0,
        );
        let origin = Vector3::new(x, y, 100.0);
        let hit = scene.hit(&origin, &dir).expect("hit");
        let z = field.height_at(hit.x, hit.y).expect("inside");
        assert!((hit.z - z).abs() < 1e-9, "{} vs {z}", hit.z);
    }
    for (i, j) in [(0, 0), (37, 55), (120, 100)] {
        let (x, y) = (1000.0 + 0.5 * i as f64, 2000.0 + 0.5 * j as f64);
        assert_eq!(field.height_at(x, y), Some(field.node(i, j)));
    }
    assert_eq!(field.height_at(999.0, 2010.0), None);
}

#[test]
fn textured_terrain_renders_with_detail() {
    let field = terrain();
    let (vertices, triangles) = field.mesh();
    let material = Material::Noise {
        noise: Box::new(Noise::new(11)),
        mean: 0.45,
        amplitude: 0.5,
        scale: 8.0,
        octaves: 6,
    };
    let scene = Scene::new(
        &vertices,
        &triangles,
        vec![0; triangles.len()],
        vec![material],
    )
    .expect("scene");
    let camera = BrownCamera::new(200, 150, 180.0).expect("camera");
    // 30 m above the terrain: the 200 × 150 view covers about 33 m × 25 m of it.
    let pose = Pose::look_at(
        &Vector3::new(1030.0, 2025.0, 80.0),
        &Vector3::new(1030.0, 2025.1, 50.0),
    )
    .expect("pose");
    let img = render(&scene, &camera, 200, 150, &pose, &RenderOptions::default())
        .expect("render")
        .to_grey();
    assert!(
        img.data.iter().all(|&v| v > 0.0),
        "every pixel sees the terrain"
    );
    // Local contrast at the pixel scale: neighbouring pixels differ.
    let diffs = img
        .data
        .windows(2)
        .filter(|w| (w[0] - w[1]).abs() > 0.005)
        .count();
    assert!(diffs > img.data.len() / 4, "{diffs}");
}

/// The heightfield ray walk finds the same first hit as a general BVH over the same triangles
/// (parry3d), for rays from above, oblique and grazing, from inside and outside the grid.
#[test]
fn field_tracer_agrees_with_a_bvh_on_the_same_triangles() {
    use parry3d_f64::math::Vector as PVector;
    use parry3d_f64::query::{Ray, RayCast};
    use parry3d_f64::shape::TriMesh;
    use timesift_synth::terrain::FieldTracer;
    let field = terrain();
    let (vertices, triangles) = field.mesh();
    let mesh = TriMesh::new(
        vertices
            .iter()
            .map(|v| PVector::new(v.x, v.y, v.z))
            .collect(),
        triangles.clone(),
    )
    .expect("mesh");
    let tracer = FieldTracer::new(field.clone());
    let mut rng = SeededRng::new(11);
    let (mut hits, mut misses) = (0, 0);
    for k in 0..20_000 {
        let origin = Vector3::new(
            rng.uniform_range(990.0, 1070.0),
            rng.uniform_range(1990.0, 2060.0),
            rng.uniform_range(50.0, 75.0),
        );
        let dir = Vector3::new(
            rng.uniform_range(-1.0, 1.0),
            rng.uniform_range(-1.0, 1.0),
            if k % 3 == 0 {
                rng.uniform_range(-0.2, 0.05)
            } else {
                rng.uniform_range(-1.0, -0.1)
            },
        );
        let ray = Ray::new(
            PVector::new(origin.x, origin.y, origin.z),
            PVector::new(dir.x, dir.y, dir.z),
        );
        let expected = mesh.cast_local_ray_and_get_normal(&ray, 1e6, false);
        let got = tracer.cast(&origin, &dir, 1e6);
        match (expected, got) {
            (Some(e), Some(g)) => {
                hits += 1;
                assert!(
                    (e.time_of_impact - g.t).abs() < 1e-7 * (1.0 + g.t),
                    "ray {k}: t {} vs {}",
                    e.time_of_impact,
                    g.t
                );
                let n = Vector3::new(e.normal.x, e.normal.y, e.normal.z);
                assert!(
                    n.dot(&g.normal).abs() > 1.0 - 1e-9
                        || (e.subshape as usize / 2 != g.triangle / 2)
                );
            }
            (None, None) => misses += 1,
            (e, g) => panic!(
                "ray {k}: BVH {:?}, walk {:?}",
                e.map(|h| h.time_of_impact),
                g.map(|h| h.t)
            ),
        }
    }
    assert!(hits > 5_000 && misses > 500, "{hits} hits, {misses} misses");
}

/// Shading a pixel once at its samples' mean point (when they land on one smooth material)
/// matches averaging every sample's shading: the texture is band-limited at the pixel scale.
#[test]
fn shading_once_per_uniform_pixel_matches_per_sample_shading() {
    use nalgebra::Vector2;
    use timesift_core::CameraModel;
    use timesift_synth::render::{FieldMaterial, SceneBuilder};
    let mut builder = SceneBuilder::new();
    // Finest octave 5 m / 2⁶ = 8 cm, half the ~17 cm ground sampling distance, as in the scenes.
    let m = builder.material(Material::Noise {
        noise: Box::new(Noise::new(3)),
        mean: 0.45,
        amplitude: 0.5,
        scale: 5.0,
        octaves: 7,
    });
    builder.add_field(terrain(), false, FieldMaterial::Uniform(m));
    let scene = builder.build().expect("scene");
    let camera = BrownCamera::new(200, 150, 180.0).expect("camera");
    let pose = Pose::look_at(
        &Vector3::new(1030.0, 2025.0, 80.0),
        &Vector3::new(1030.0, 2025.1, 50.0),
    )
    .expect("pose");
    let options = RenderOptions {
        supersampling: 2,
        shadows: false,
    };
    let fast = render(&scene, &camera, 200, 150, &pose, &options).expect("render");
    let (centre, world_from_cam) = (pose.center(), pose.rotation.inverse());
    let (mut sum, mut worst) = (0.0f64, 0.0f64);
    for row in 0..150 {
        for col in 0..200 {
            let mut reference = 0.0;
            for s in 0..4 {
                let px = Vector2::new(
                    col as f64 + 0.25 + 0.5 * (s % 2) as f64,
                    row as f64 + 0.25 + 0.5 * (s / 2) as f64,
                );
                let ray = world_from_cam * camera.unproject(&px).expect("ray");
                reference += scene.trace(&centre, &ray, false).x / 4.0;
            }
            let d = (fast.get(col, row)[0] as f64 - reference).abs();
            sum += d;
            worst = worst.max(d);
        }
    }
    let mean = sum / 30_000.0;
    println!("per-pixel vs per-sample shading: mean |Δ| {mean:.5}, worst {worst:.5}");
    assert!(mean < 0.005 && worst < 0.05, "mean {mean}, worst {worst}");
}
