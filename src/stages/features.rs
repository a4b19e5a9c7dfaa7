//! The `features` stage: keypoints and descriptors of every image, one file per image under
//! `work/features/`, so that a run resumes where it stopped and memory holds one image's
//! features per thread.

use rayon::prelude::*;
use timesift_features::{
    DetectorOptions, FeatureExtractor, Features, GreyImage, KeypointLimit, LdbExtractor, Mask,
    SiftExtractor, SiftNormalization,
};
use timesift_matching::storage::{read_features, write_features};

use super::cache::{stage_error, start_with_settings};
use super::{PipelineStage, Stage};
use crate::config::FeatureMethod;
use crate::film::ImageSource;
use crate::{Project, ProjectError};

/// The `features` stage.
pub(super) struct FeaturesStage;

impl PipelineStage for FeaturesStage {
    fn stage(&self) -> Stage {
        Stage::Features
    }
    fn inputs(&self, _: &Project) -> Vec<(std::path::PathBuf, Stage)> {
        Vec::new()
    }
    fn outputs(&self, project: &Project) -> Vec<std::path::PathBuf> {
        (0..project.images.len())
            .map(|i| project.layout().feature_file(i))
            .collect()
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let film = super::fiducials::fiducials_stage(project)?;
        let extracted = features_stage(project)?;
        let mut line = format!(
            "features of {extracted} images extracted ({} cached)",
            project.images.len() - extracted
        );
        if let Some(film) = film {
            line.push_str(&format!("; {}", film.summary()));
        }
        Ok(line)
    }
}

/// The built-in extractor `[align] features` names, and the settings its features are recorded
/// as made with.
fn builtin_extractor(project: &Project) -> (Box<dyn FeatureExtractor>, serde_json::Value) {
    let detector = DetectorOptions {
        limit: Some(KeypointLimit::spread(project.config.align.max_keypoints)),
        // COLMAP's peak threshold: more keypoints in weak texture, which epochs years apart need.
        contrast_threshold: 0.02,
        ..DetectorOptions::default()
    };
    let extractor: Box<dyn FeatureExtractor> = match project.config.align.features {
        FeatureMethod::Sift => Box::new(SiftExtractor {
            detector,
            normalization: SiftNormalization::Root,
        }),
        FeatureMethod::Ldb => Box::new(LdbExtractor { detector }),
    };
    let settings = serde_json::json!({
        "features": project.config.align.features,
        "max_keypoints": project.config.align.max_keypoints,
        "contrast_threshold": detector.contrast_threshold,
    });
    (extractor, settings)
}

/// Extracts the features of every image whose feature file is missing or unreadable, with the
/// extractor `[align] features` names.
pub fn features_stage(project: &Project) -> Result<usize, ProjectError> {
    let (extractor, settings) = builtin_extractor(project);
    extract_with(project, extractor.as_ref(), &settings)
}

/// The `features` stage with any extractor: a caller's own (a research group's detector, a
/// learned descriptor) in place of the built-in ones, for the stages after it to use as they
/// would SIFT's. Returns how many images were extracted. The extractor's name is recorded with
/// the features, so that another extractor, or the built-in one of a later `timesift run`,
/// redoes them and the matches.
pub fn extract_features(
    project: &Project,
    extractor: &dyn FeatureExtractor,
) -> Result<usize, ProjectError> {
    let settings = serde_json::json!({ "extractor": extractor.name() });
    extract_with(project, extractor, &settings)
}

/// The settings the feature files are made with: `settings` and the scans' interior
/// orientations.
fn recorded_settings(
    project: &Project,
    source: &ImageSource,
    settings: &serde_json::Value,
) -> serde_json::Value {
    let mut settings = settings.clone();
    let seen = source.fingerprint(project);
    if !seen.is_empty() {
        settings["image_source"] = seen.into();
    }
    settings
}

/// The stage's first step (`features-prepare`): the scans' interior orientations, then the
/// settings recorded, removing the features (and matches) an earlier run made otherwise. The
/// files it owns.
pub(super) fn prepare(project: &Project) -> Result<Vec<std::path::PathBuf>, ProjectError> {
    let (_, settings) = builtin_extractor(project);
    prepare_with(project, &settings)?;
    let layout = project.layout();
    let mut owned = vec![
        crate::layout::Layout::settings_file(&layout.features_dir()),
        layout.features_dir().join("images.json"),
        layout.fiducials_settings(),
        layout.fiducials_json(),
        layout.fiducials_csv(),
        layout.fiducials_sheet(),
    ];
    owned.extend(project.film.keys().map(|c| layout.fiducials_frame(c)));
    Ok(owned)
}

fn prepare_with(
    project: &Project,
    settings: &serde_json::Value,
) -> Result<ImageSource, ProjectError> {
    let layout = project.layout();
    // Scans are seen through their interior orientations: new ones redo their features.
    super::fiducials::fiducials_stage(project)?;
    let source = ImageSource::of(project)?;
    start_with_settings(
        "features",
        &layout.features_dir(),
        "feat",
        &recorded_settings(project, &source, settings),
        &[(&layout.matches_dir(), "match")],
    )?;
    forget_changed_images(project)?;
    Ok(source)
}

/// What one feature file was made from, recorded per image index in
/// `work/features/images.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
struct ImageRecord {
    /// The image's name (path in the project).
    name: String,
    /// Its size and modification time ([`super::cache::file_stamp`]).
    stamp: serde_json::Value,
    /// A hash of its bytes: a copied project (new times, same photos) keeps its features.
    content: Option<String>,
}

/// Removes the feature files, and the match files, of every image index whose image is not the
/// one they were made from: an image replaced, edited, added or removed (indices shift) since.
/// A feature file is named by index alone; without this, a replaced photo would keep its old
/// features and another photo could inherit a removed one's. An image whose size or time
/// changed is read whole once to tell an edit from a copy.
fn forget_changed_images(project: &Project) -> Result<(), ProjectError> {
    let layout = project.layout();
    let record = layout.features_dir().join("images.json");
    let recorded: Vec<ImageRecord> = crate::report::read_sealed_json::<ImageRecords>(&record)
        .map(|r| r.images)
        .unwrap_or_default();
    let current: Vec<ImageRecord> = (0..project.images.len())
        .into_par_iter()
        .map(|i| {
            let name = project.images[i].name.clone();
            let path = project.image_path(timesift_core::ImageId::from(i));
            let stamp = super::cache::file_stamp(&path);
            let content = match recorded.get(i) {
                Some(r) if r.name == name && r.stamp == stamp => r.content.clone(),
                _ => super::cache::file_content_hash(&path),
            };
            ImageRecord {
                name,
                stamp,
                content,
            }
        })
        .collect();
    if recorded == current {
        return Ok(());
    }
    let changed = |i: usize| match (recorded.get(i), current.get(i)) {
        (Some(r), Some(c)) => r.name != c.name || r.content.is_none() || r.content != c.content,
        _ => true,
    };
    let remove = |path: &std::path::Path| match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(stage_error(
            "features",
            format!("{}: cannot remove: {e}", path.display()),
        )),
        _ => Ok(()),
    };
    let mut forgotten = 0;
    for i in (0..recorded.len().max(current.len())).filter(|&i| changed(i)) {
        let file = layout.feature_file(i);
        forgotten += usize::from(file.is_file());
        remove(&file)?;
    }
    if let Ok(entries) = std::fs::read_dir(layout.matches_dir()) {
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let pair = name
                .strip_suffix(".match")
                .and_then(|stem| stem.split_once('_'))
                .and_then(|(a, b)| Some((a.parse::<usize>().ok()?, b.parse::<usize>().ok()?)));
            if pair.is_some_and(|(a, b)| changed(a) || changed(b)) {
                remove(&entry.path())?;
            }
        }
    }
    if forgotten > 0 {
        tracing::info!(
            forgotten,
            "images changed since their features: features redone"
        );
    }
    crate::report::write_sealed_json(&record, &ImageRecords { images: current })
}

/// `work/features/images.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
struct ImageRecords {
    /// Per image index.
    images: Vec<ImageRecord>,
}

/// A unit of the `features` step: the images of `part` (in project order) whose feature file
/// is missing or unreadable. `features-prepare` must have recorded today's settings. The files
/// it owns.
pub(super) fn unit(
    project: &Project,
    part: super::Part,
) -> Result<Vec<std::path::PathBuf>, ProjectError> {
    let (extractor, settings) = builtin_extractor(project);
    let layout = project.layout();
    let source = ImageSource::of(project)?;
    let wanted = recorded_settings(project, &source, &settings);
    let settings_path = crate::layout::Layout::settings_file(&layout.features_dir());
    let recorded = crate::report::read_sealed_json::<serde_json::Value>(&settings_path).ok();
    if recorded.as_ref() != Some(&wanted) {
        return Err(stage_error(
            "features",
            format!(
                "{} does not record this project's feature settings: run the features-prepare \
                 step first",
                settings_path.display()
            ),
        ));
    }
    let images: Vec<usize> = part.range(project.images.len()).collect();
    extract_images(project, &source, extractor.as_ref(), &images)?;
    Ok(images.iter().map(|&i| layout.feature_file(i)).collect())
}

/// Extracts the features of every image whose feature file is missing or unreadable; `settings`
/// is what the feature files are recorded as made with.
fn extract_with(
    project: &Project,
    extractor: &dyn FeatureExtractor,
    settings: &serde_json::Value,
) -> Result<usize, ProjectError> {
    let source = prepare_with(project, settings)?;
    let all: Vec<usize> = (0..project.images.len()).collect();
    let extracted = extract_images(project, &source, extractor, &all)?;
    tracing::info!(extracted, total = project.images.len(), "features");
    Ok(extracted)
}

/// Extracts the features of those of `images` whose feature file is missing or unreadable, in
/// parallel; how many were extracted.
fn extract_images(
    project: &Project,
    source: &ImageSource,
    extractor: &dyn FeatureExtractor,
    images: &[usize],
) -> Result<usize, ProjectError> {
    let layout = project.layout();
    let todo: Vec<usize> = images
        .iter()
        .copied()
        .filter(|&i| read_features(&layout.feature_file(i)).is_err())
        .collect();
    let failures: Vec<String> = todo
        .par_iter()
        .filter_map(|&i| {
            let result = extract_one(project, source, i, extractor)
                .map_err(|e| match e.contains(&project.images[i].name) {
                    true => e,
                    false => format!("{}: {e}", project.images[i].name),
                })
                .and_then(|f| {
                    write_features(&layout.feature_file(i), &f.keypoints, &f.descriptors)
                        .map_err(|e| e.to_string())
                });
            result.err()
        })
        .collect();
    if let Some(first) = failures.first() {
        return Err(stage_error(
            "features",
            format!(
                "{} of {} images failed; first: {first}",
                failures.len(),
                todo.len()
            ),
        ));
    }
    Ok(todo.len())
}

/// The features of image `i` as the stages see it: a scan resampled to its camera's frame,
/// with keypoints only on the photograph (never on the film's edge, marks or data strip).
fn extract_one(
    project: &Project,
    source: &ImageSource,
    i: usize,
    extractor: &dyn FeatureExtractor,
) -> Result<Features, String> {
    let seen = source.read(project, i, true).map_err(|e| e.to_string())?;
    let grey = GreyImage::from_io(&seen.image).map_err(|e| e.to_string())?;
    let mask_bytes: Option<Vec<u8>> = seen
        .usable
        .as_ref()
        .map(|u| u.iter().map(|&b| b as u8).collect());
    let mask = mask_bytes
        .as_deref()
        .map(|b| Mask::new(seen.image.width as usize, seen.image.height as usize, b))
        .transpose()
        .map_err(|e| e.to_string())?;
    extractor
        .extract(&grey, mask.as_ref())
        .map_err(|e| e.to_string())
}
