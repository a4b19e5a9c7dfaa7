//! The invariants of ARCHITECTURE.md that a machine can check, from `cargo metadata`: which
//! crate may depend on which.

use std::collections::BTreeMap;
use std::process::Command;

/// `cargo metadata` of the workspace's own packages.
fn metadata() -> serde_json::Value {
    let out = Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON")
}

/// Normal (non-dev, non-build) dependencies of every workspace package, by package name.
fn dependencies() -> BTreeMap<String, Vec<String>> {
    let meta = metadata();
    let mut deps = BTreeMap::new();
    for p in meta["packages"].as_array().expect("packages") {
        let names = p["dependencies"]
            .as_array()
            .expect("dependencies")
            .iter()
            .filter(|d| d["kind"].is_null())
            .map(|d| d["name"].as_str().expect("name").to_string())
            .collect();
        deps.insert(p["name"].as_str().expect("name").to_string(), names);
    }
    deps
}

const STAGE_CRATES: [&str; 7] = [
    "timesift-film",
    "timesift-features",
    "timesift-matching",
    "timesift-align",
    "timesift-dense",
    "timesift-raster",
    "timesift-change",
];

#[test]
fn no_stage_crate_depends_on_a_sibling_stage() {
    let deps = dependencies();
    for stage in STAGE_CRATES {
        let d = deps.get(stage).expect("the crate exists");
        for other in STAGE_CRATES.iter().filter(|s| **s != stage) {
            assert!(!d.iter().any(|n| n == other), "{stage} depends on {other}");
        }
    }
}

#[test]
fn core_is_the_vocabulary_and_depends_on_nalgebra_and_thiserror_only() {
    let deps = dependencies();
    assert_eq!(deps["timesift-core"], vec!["nalgebra", "thiserror"]);
}

#[test]
fn only_the_root_and_the_benches_use_the_pipeline_and_the_scene_generator() {
    for (name, d) in dependencies() {
        // The fuzz harness hands `project.toml` to the project's own validation.
        if name == "timesift" || name == "xtask" || name == "timesift-fuzz" {
            continue;
        }
        assert!(!d.iter().any(|n| n == "timesift"), "{name}: {d:?}");
        // The evaluation rebuilds the scenes it judges against.
        if name != "timesift-eval" {
            assert!(!d.iter().any(|n| n == "timesift-synth"), "{name}: {d:?}");
        }
    }
}

#[test]
fn file_formats_are_io_s_and_dense_raster_and_film_touch_no_file() {
    let deps = dependencies();
    for (name, d) in &deps {
        for format in ["tiff", "exr", "las", "kamadak-exif", "flate2", "csv"] {
            assert!(
                name == "timesift-io" || !d.iter().any(|n| n == format),
                "{name} uses {format}: file formats belong to timesift-io"
            );
        }
        // Stated exceptions: synth renders JPEGs, change draws its maps, the root and the
        // benches encode PNGs, the fuzz harness encodes a JPEG seed.
        let image_ok = [
            "timesift-io",
            "timesift-synth",
            "timesift-change",
            "timesift",
            "xtask",
            "timesift-fuzz",
        ];
        assert!(
            image_ok.contains(&name.as_str()) || !d.iter().any(|n| n == "image"),
            "{name} uses image"
        );
    }
    for pure in ["timesift-dense", "timesift-raster", "timesift-film"] {
        assert!(
            !deps[pure].iter().any(|n| n == "timesift-io"),
            "{pure} depends on timesift-io"
        );
    }
}

/// Every package but the benches can be published: the metadata crates.io shows, a readme and
/// license texts in the package, and a version on every dependency on another timesift crate
/// (a path alone is refused by `cargo package`; dev-dependencies without one are dropped).
#[test]
fn every_library_crate_is_ready_for_crates_io() {
    let meta = metadata();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for p in meta["packages"].as_array().expect("packages") {
        let name = p["name"].as_str().expect("name");
        if name == "xtask" || name == "timesift-fuzz" {
            assert_eq!(
                p["publish"],
                serde_json::json!([]),
                "{name} is not published"
            );
            continue;
        }
        for key in ["description", "license", "repository", "readme"] {
            assert!(p[key].is_string(), "{name}: no `{key}`");
        }
        for key in ["keywords", "categories"] {
            let n = p[key].as_array().map_or(0, Vec::len);
            assert!((1..=5).contains(&n), "{name}: {n} {key}");
        }
        let dir = std::path::Path::new(p["manifest_path"].as_str().expect("manifest"))
            .parent()
            .expect("package folder")
            .to_path_buf();
        for file in [
            "LICENSE-MIT",
            "LICENSE-APACHE",
            p["readme"].as_str().unwrap_or(""),
        ] {
            assert!(dir.join(file).is_file(), "{name}: no {file}");
        }
        for d in p["dependencies"].as_array().expect("dependencies") {
            let dep = d["name"].as_str().expect("name");
            if dep.starts_with("timesift") && d["kind"].is_null() {
                assert_ne!(d["req"], "*", "{name} depends on {dep} without a version");
            }
        }
    }
    assert!(root.join("LICENSE-MIT").is_file() && root.join("LICENSE-APACHE").is_file());
}
