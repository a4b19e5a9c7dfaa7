//! `cargo xtask bench-methods`: every `synth` scene × every co-registration strategy. Each scene
//! is rendered once and its features and matches computed once (they do not depend on the
//! strategy); then the `align` stage runs per strategy and is compared with the truth: per
//! strategy and epoch, images oriented, check-point RMSE (dE, dN, dH) in metres and in ground
//! sampling distances, camera-centre RMSE, reprojection RMS, inter-epoch tie points, the
//! disagreement of check points between each epoch and the reference epoch, and wall time.
//! Written as `methods.md` and `methods.json` in the output folder and printed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use timesift::Project;
use timesift::config::AlignMethod;
use timesift::stages::{Stage, run, run_stage};
use timesift::truth::{EpochAccuracy, epoch_accuracy, ground_sampling_distance, triple};

/// The strategies, in the papers' order.
const METHODS: [(&str, AlignMethod); 5] = [
    ("timesift", AlignMethod::Timesift),
    ("independent", AlignMethod::Independent),
    ("chunk", AlignMethod::Chunk),
    ("stp", AlignMethod::Stp),
    ("msfm", AlignMethod::Msfm),
];

/// What to run.
pub struct MethodsBench {
    pub scenes: Vec<String>,
    pub methods: Vec<String>,
    pub scale: String,
    pub seed: u64,
    pub out: PathBuf,
}

/// One strategy on one epoch of one scene (or its failure).
#[derive(Debug, Clone, serde::Serialize)]
struct Row {
    scene: String,
    method: String,
    #[serde(flatten)]
    accuracy: Option<EpochAccuracy>,
    seconds: f64,
    error: Option<String>,
}

pub fn run_bench(bench: &MethodsBench) -> anyhow::Result<()> {
    let scale: timesift_synth::scenes::Scale = bench
        .scale
        .parse()
        .map_err(|e: String| anyhow::anyhow!("--scale: {e}"))?;
    std::fs::create_dir_all(&bench.out).with_context(|| bench.out.display().to_string())?;
    let mut rows = Vec::new();
    for scene in &bench.scenes {
        let dir = bench.out.join(scene);
        let _ = std::fs::remove_dir_all(&dir);
        let spec = timesift_synth::scenes::build(scene, scale, bench.seed)?;
        timesift_synth::writer::write_scene(
            &spec,
            &dir,
            &timesift_synth::writer::WriteOptions::default(),
        )?;
        let project = Project::load(&dir)?;
        let start = Instant::now();
        run(&project, Some(Stage::Features), Some(Stage::Match))?;
        println!(
            "{scene}: features and matches in {:.1} s",
            start.elapsed().as_secs_f64()
        );
        let gsd = ground_sampling_distance(&project)?;
        println!("{scene}: ground sampling distance at the check points {gsd:.4} m");
        for name in &bench.methods {
            let method = METHODS
                .iter()
                .find(|(n, _)| n == name)
                .map(|m| m.1)
                .with_context(|| format!("unknown method {name}"))?;
            let mut project = Project::load(&dir)?;
            project.config.align.method = method;
            let start = Instant::now();
            let result = run_stage(&project, Stage::Align);
            let seconds = start.elapsed().as_secs_f64();
            match result {
                Ok(_) => {
                    let kept = dir.join(format!("out-{name}"));
                    let _ = std::fs::remove_dir_all(&kept);
                    std::fs::rename(dir.join("out"), &kept)?;
                    rows.extend(evaluate(scene, name, &project, &kept, gsd, seconds)?);
                }
                Err(e) => rows.push(Row {
                    scene: scene.clone(),
                    method: name.clone(),
                    accuracy: None,
                    seconds,
                    error: Some(e.to_string()),
                }),
            }
        }
    }
    let markdown = table(&rows) + &findings(&rows);
    println!("{markdown}");
    std::fs::write(bench.out.join("methods.md"), &markdown)?;
    std::fs::write(
        bench.out.join("methods.json"),
        serde_json::to_string_pretty(&rows)?,
    )?;
    println!("written: {}", bench.out.join("methods.{md,json}").display());
    Ok(())
}

fn evaluate(
    scene: &str,
    method: &str,
    project: &Project,
    out: &Path,
    gsd: f64,
    seconds: f64,
) -> anyhow::Result<Vec<Row>> {
    Ok(epoch_accuracy(project, out, gsd)?
        .into_iter()
        .map(|a| Row {
            scene: scene.to_string(),
            method: method.to_string(),
            accuracy: Some(a),
            seconds,
            error: None,
        })
        .collect())
}

fn table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| scene | method | epoch | oriented | check RMSE dE/dN/dH (m) | (GSD) | epoch − ref. (m) \
         | centre RMSE (m) | RMS px | inter-epoch ties | s |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let Some(a) = &r.accuracy else {
            s.push_str(&format!(
                "| {} | {} | – | failed: {} | | | | | | | {:.1} |\n",
                r.scene,
                r.method,
                r.error.as_deref().unwrap_or("").replace('|', "/"),
                r.seconds
            ));
            continue;
        };
        s.push_str(&format!(
            "| {} | {} | {} | {}/{} | {} | {} | {} | {} | {} | {} | {:.1} |\n",
            r.scene,
            r.method,
            a.epoch,
            a.images_oriented,
            a.images_given,
            triple(a.check_rmse_m, 3),
            triple(a.check_rmse_gsd, 2),
            triple(a.disagreement_m, 3),
            triple(a.centre_rmse_m, 3),
            a.rms_px.map_or("–".into(), |v| format!("{v:.3}")),
            a.inter_epoch_tie_points,
            r.seconds
        ));
    }
    s
}

/// (check dH RMS over the epochs in GSD, later epochs' dH disagreement RMS in m).
type Summary = (Option<f64>, Option<f64>);

/// The papers' questions answered from the rows, per scene: how high each strategy's check
/// points are off (RMS of dH over the epochs, in GSD) and how far the later epochs disagree with
/// the reference epoch in height (RMS of the epoch − reference dH over the later epochs, m).
/// The reference is each scene's first epoch, as `synth` writes it.
fn findings(rows: &[Row]) -> String {
    let mut scenes: Vec<&str> = Vec::new();
    let mut methods: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    let rms = |v: &[f64]| {
        (!v.is_empty()).then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
    };
    // (check dH RMS in GSD, later epochs' dH disagreement RMS in m) per scene and method.
    let summary = |scene: &str, method: &str| -> Summary {
        let epochs: Vec<&EpochAccuracy> = rows
            .iter()
            .filter(|r| r.scene == scene && r.method == method)
            .filter_map(|r| r.accuracy.as_ref())
            .collect();
        let check: Vec<f64> = epochs
            .iter()
            .filter_map(|a| a.check_rmse_gsd.map(|c| c[2]))
            .collect();
        let apart: Vec<f64> = epochs
            .iter()
            .skip(1)
            .filter_map(|a| a.disagreement_m.map(|d| d[2]))
            .collect();
        (rms(&check), rms(&apart))
    };
    let cell =
        |v: Option<f64>, digits: usize| v.map_or("–".to_string(), |v| format!("{v:.digits$}"));
    let mut s = String::from(
        "\n## Height, per scene: check dH RMS over the epochs (GSD) · epoch − reference dH RMS \
         over the later epochs (m)\n\n| scene |",
    );
    for m in &methods {
        s.push_str(&format!(" {m} |"));
    }
    s.push_str(&format!("\n|---|{}\n", "---|".repeat(methods.len())));
    for scene in &scenes {
        s.push_str(&format!("| {scene} |"));
        for m in &methods {
            let (check, apart) = summary(scene, m);
            s.push_str(&format!(" {} · {} |", cell(check, 2), cell(apart, 3)));
        }
        s.push('\n');
    }
    // The comparisons the papers make, scene by scene.
    let mut compare = |title: &str, a: &str, b: &str, pick: fn(Summary) -> Option<f64>| {
        if !(methods.contains(&a) && methods.contains(&b)) {
            return;
        }
        let (mut yes, mut even, mut no) = (Vec::new(), Vec::new(), Vec::new());
        for scene in &scenes {
            if let (Some(x), Some(y)) = (pick(summary(scene, a)), pick(summary(scene, b))) {
                let entry = format!("{scene} ({x:.2} vs {y:.2})");
                // Within 10 % (or 0.01) is a tie: synthetic noise, not a finding.
                if (x - y).abs() <= (0.1 * x.max(y)).max(0.01) {
                    even.push(entry);
                } else if x > y {
                    yes.push(entry);
                } else {
                    no.push(entry);
                }
            }
        }
        let list = |v: &[String]| {
            if v.is_empty() {
                "–".to_string()
            } else {
                v.join(", ")
            }
        };
        s.push_str(&format!(
            "\n- {title}: on {} of {} scenes: {}; within 10 %: {}; the opposite: {}\n",
            yes.len(),
            yes.len() + even.len() + no.len(),
            list(&yes),
            list(&even),
            list(&no),
        ));
    };
    compare(
        "`chunk` worse than `timesift` in height (check dH, GSD)",
        "chunk",
        "timesift",
        |(check, _)| check,
    );
    compare(
        "`timesift` disagrees more than `stp` between epochs in height (m)",
        "timesift",
        "stp",
        |(_, apart)| apart,
    );
    compare(
        "`independent` disagrees more than `timesift` between epochs in height (m)",
        "independent",
        "timesift",
        |(_, apart)| apart,
    );
    s
}
