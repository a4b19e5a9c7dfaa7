//! Rendering agrees with the camera model: a checkerboard plane rendered through a distorted
//! `brown` camera at a known pose; every inner corner found by sub-pixel refinement in the image
//! lies within 0.1 px of where `timesift-core` projects it.

use nalgebra::{Vector2, Vector3};
use timesift_core::{BrownCamera, Pose, project_world};
use timesift_synth::render::{GreyImage, Material, RenderOptions, Scene, render};

const SQUARE: f64 = 0.1;

fn board() -> Scene {
    // A 1.6 m × 1.2 m board in the plane z = 0, corner at the origin.
    let (w, h) = (16.0 * SQUARE, 12.0 * SQUARE);
    let vertices = [
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(w, 0.0, 0.0),
        Vector3::new(w, h, 0.0),
        Vector3::new(0.0, h, 0.0),
    ];
    let mut scene = Scene::new(
        &vertices,
        &[[0, 1, 2], [0, 2, 3]],
        vec![0, 0],
        vec![Material::Checker {
            origin: Vector3::zeros(),
            u: Vector3::x(),
            v: Vector3::y(),
            size: SQUARE,
            dark: 0.1,
            light: 0.9,
        }],
    )
    .expect("scene");
    scene.sun = Vector3::z();
    scene.ambient = 1.0;
    scene
}

/// Sub-pixel corner refinement (Förstner / OpenCV cornerSubPix): the corner q makes every image
/// gradient g(p) in a window orthogonal to p − q, so q = (Σ g gᵀ)⁻¹ Σ g gᵀ p; iterated with the
/// window re-centred on q.
fn refine_corner(img: &GreyImage, start: Vector2<f64>, radius: i64) -> Option<Vector2<f64>> {
    let mut q = start;
    for _ in 0..20 {
        let (cx, cy) = (q.x.floor() as i64, q.y.floor() as i64);
        let mut a = nalgebra::Matrix2::<f64>::zeros();
        let mut b = Vector2::<f64>::zeros();
        for j in cy - radius..=cy + radius {
            for i in cx - radius..=cx + radius {
                if i < 1 || j < 1 || i + 1 >= img.width as i64 || j + 1 >= img.height as i64 {
                    return None;
                }
                let (iu, ju) = (i as usize, j as usize);
                let g = Vector2::new(
                    0.5 * (img.get(iu + 1, ju) - img.get(iu - 1, ju)) as f64,
                    0.5 * (img.get(iu, ju + 1) - img.get(iu, ju - 1)) as f64,
                );
                // Pixel centre, Gaussian weight on the distance to the current estimate.
                let p = Vector2::new(i as f64 + 0.5, j as f64 + 0.5);
                let w = (-(p - q).norm_squared() / (radius as f64 * radius as f64)).exp();
                let ggt = g * g.transpose() * w;
                a += ggt;
                b += ggt * p;
            }
        }
        let next = a.try_inverse()? * b;
        let moved = (next - q).norm();
        q = next;
        if moved < 1e-4 {
            break;
        }
    }
    Some(q)
}

#[test]
fn rendered_corners_match_the_camera_model() {
    let mut camera = BrownCamera::new(640, 480, 520.0).expect("camera");
    camera.cx = 6.5;
    camera.cy = -4.0;
    camera.k1 = -0.18;
    camera.k2 = 0.06;
    camera.p1 = 0.001;
    camera.p2 = -0.0008;
    camera.b1 = 0.4;
    // Looking at the board from 1.7 m, obliquely.
    let pose =
        Pose::look_at(&Vector3::new(0.55, 0.25, 1.7), &Vector3::new(0.8, 0.6, 0.0)).expect("pose");
    let img = render(
        &board(),
        &camera,
        640,
        480,
        &pose,
        &RenderOptions {
            supersampling: 6,
            shadows: false,
        },
    )
    .expect("render")
    .to_grey();
    let mut errors = Vec::new();
    for i in 1..16 {
        for j in 1..12 {
            let x = Vector3::new(i as f64 * SQUARE, j as f64 * SQUARE, 0.0);
            let Ok(px) = project_world(&camera, &pose, &x) else {
                continue;
            };
            if px.x < 12.0 || px.y < 12.0 || px.x > 628.0 || px.y > 468.0 {
                continue;
            }
            // Start half a pixel off, as a detector would.
            let found = refine_corner(&img, px + Vector2::new(0.4, -0.3), 4).expect("corner");
            errors.push((found - px).norm());
        }
    }
    let worst = errors.iter().fold(0.0f64, |m, e| m.max(*e));
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    println!(
        "{} corners: mean error {mean:.4} px, worst {worst:.4} px",
        errors.len()
    );
    assert!(errors.len() > 60, "{} corners in view", errors.len());
    assert!(worst < 0.1, "worst corner error {worst} px");
}

#[test]
fn mismatched_materials_are_errors() {
    let v = [Vector3::zeros(), Vector3::x(), Vector3::y()];
    assert!(Scene::new(&v, &[[0, 1, 2]], vec![], vec![Material::Flat(0.5)]).is_err());
    assert!(Scene::new(&v, &[[0, 1, 2]], vec![3], vec![Material::Flat(0.5)]).is_err());
}

/// Each triangle shows its own material: two squares side by side, dark west and light east.
#[test]
fn triangles_show_their_own_materials() {
    let v = [
        Vector3::new(-1.0, -1.0, 0.0),
        Vector3::new(0.0, -1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(-1.0, 1.0, 0.0),
        Vector3::new(1.0, -1.0, 0.0),
        Vector3::new(1.0, 1.0, 0.0),
    ];
    let mut scene = Scene::new(
        &v,
        &[[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]],
        vec![0, 0, 1, 1],
        vec![Material::Flat(0.2), Material::Flat(0.8)],
    )
    .expect("scene");
    scene.sun = Vector3::z();
    scene.ambient = 1.0;
    let camera = BrownCamera::new(40, 40, 40.0).expect("camera");
    // Nadir, image x towards east.
    let pose = Pose::from_rotation_and_center(
        timesift_synth::flight::nadir_rotation(0.0),
        &Vector3::new(0.0, 0.0, 1.5),
    );
    let img = render(&scene, &camera, 40, 40, &pose, &RenderOptions::default())
        .expect("render")
        .to_grey();
    assert!((img.get(5, 20) - 0.2).abs() < 1e-6, "{}", img.get(5, 20));
    assert!((img.get(34, 20) - 0.8).abs() < 1e-6, "{}", img.get(34, 20));
}
