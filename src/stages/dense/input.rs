//! What the dense stage matches: each epoch's oriented images as views (cameras and poses
//! from `out/cameras.json`) and the sparse points they see (from `out/colmap/`).

use super::*;

/// For every project image, its index in `cameras.json`; errors name the first image that
/// does not belong (cameras.json of another project) or is missing.
pub(super) fn match_orientation(
    project: &Project,
    cameras: &Reconstruction,
) -> Result<Vec<Option<usize>>, ProjectError> {
    let path = project.layout().cameras_json();
    let by_name: BTreeMap<&str, usize> = cameras
        .images
        .iter()
        .enumerate()
        .map(|(k, im)| (im.name.as_str(), k))
        .collect();
    if let Some(stranger) = cameras
        .images
        .iter()
        .find(|im| !project.images.iter().any(|p| p.name == im.name))
    {
        return Err(ProjectError::Path {
            path,
            message: format!(
                "image \"{}\" is not in this project (cameras.json of another project? run the align stage)",
                stranger.name
            ),
        });
    }
    let mut out = Vec::with_capacity(project.images.len());
    for image in &project.images {
        let Some(&k) = by_name.get(image.name.as_str()) else {
            return Err(ProjectError::Path {
                path,
                message: format!(
                    "image \"{}\" of the project is missing (run the align stage)",
                    image.name
                ),
            });
        };
        let epoch = &project.epochs[image.epoch.index()].name;
        if &cameras.images[k].epoch != epoch {
            return Err(ProjectError::Path {
                path,
                message: format!(
                    "image \"{}\" is in epoch \"{}\" there, \"{epoch}\" in the project (run the align stage)",
                    image.name, cameras.images[k].epoch
                ),
            });
        }
        out.push(cameras.images[k].pose.map(|_| k));
    }
    Ok(out)
}

/// The oriented views of `epoch` (project image indices) and its dense input, from
/// `out/cameras.json` and the sparse points of `out/colmap/`: what the dense stage starts from
/// (benches use it to run peers on the same views).
pub fn dense_input(
    project: &Project,
    epoch: usize,
) -> Result<(Vec<usize>, EpochInput), ProjectError> {
    let layout = project.layout();
    let cameras = read_cameras_json(&layout.cameras_json())?;
    let model = read_colmap_text(&layout.colmap_dir())?;
    let oriented = match_orientation(project, &cameras)?;
    epoch_input(project, epoch, &cameras, &model, &oriented)
}

/// [`dense_input`] of every epoch, reading `out/cameras.json` and `out/colmap/` once.
pub fn dense_inputs(project: &Project) -> Result<Vec<(Vec<usize>, EpochInput)>, ProjectError> {
    let layout = project.layout();
    let cameras = read_cameras_json(&layout.cameras_json())?;
    let model = read_colmap_text(&layout.colmap_dir())?;
    let oriented = match_orientation(project, &cameras)?;
    (0..project.epochs.len())
        .map(|e| epoch_input(project, e, &cameras, &model, &oriented))
        .collect()
}

/// The epoch's oriented views (project image indices) and its dense input.
pub(super) fn epoch_input(
    project: &Project,
    epoch: usize,
    cameras: &Reconstruction,
    model: &ColmapModel,
    oriented: &[Option<usize>],
) -> Result<(Vec<usize>, EpochInput), ProjectError> {
    let images: Vec<usize> = project.epochs[epoch]
        .images
        .iter()
        .map(|i| i.index())
        .filter(|&i| oriented[i].is_some())
        .collect();
    if images.len() < 2 {
        let name = &project.epochs[epoch].name;
        return Err(stage_error(
            "dense",
            format!(
                "epoch \"{name}\": {} of its {} images were oriented ({}): too little overlap or \
                 texture, or no tie points shared with the other epochs and no GNSS priors or \
                 control points of its own to place it; dense matching needs two. Give the epoch \
                 priors or markers, or remove it from project.toml",
                images.len(),
                project.epochs[epoch].images.len(),
                project.layout().report_json().display()
            ),
        ));
    }
    let mut views = Vec::with_capacity(images.len());
    for &i in &images {
        let entry = &cameras.images[oriented[i].unwrap_or_default()];
        let camera = cameras
            .cameras
            .get(&entry.camera)
            .ok_or_else(|| ProjectError::Path {
                path: project.layout().cameras_json(),
                message: format!(
                    "image \"{}\" names camera \"{}\", which is not defined",
                    entry.name, entry.camera
                ),
            })?;
        let pose = entry.pose.ok_or_else(|| {
            stage_error("dense", format!("image \"{}\" lost its pose", entry.name))
        })?;
        views.push(View {
            camera: camera.clone(),
            cam_from_world: pose,
        });
    }
    // COLMAP image id → view index in this epoch.
    let view_of_name: BTreeMap<&str, usize> = images
        .iter()
        .enumerate()
        .map(|(v, &i)| (project.images[i].name.as_str(), v))
        .collect();
    let view_of_id: BTreeMap<u32, usize> = model
        .images
        .iter()
        .filter_map(|(id, im)| Some((*id, *view_of_name.get(im.name.as_str())?)))
        .collect();
    let points = model
        .points
        .values()
        .filter_map(|p| {
            let mut seen: Vec<usize> = p
                .track
                .iter()
                .filter_map(|(id, _)| view_of_id.get(id).copied())
                .collect();
            seen.sort_unstable();
            seen.dedup();
            (!seen.is_empty()).then_some(SparsePoint {
                position: p.xyz,
                views: seen,
            })
        })
        .collect();
    Ok((images, EpochInput { views, points }))
}

/// A fingerprint (FNV-1a over the bits) of the epoch's cameras and poses.
pub(super) fn orientation_fingerprint(input: &EpochInput) -> String {
    let mut hash = crate::stages::cache::Fnv1a::new();
    for v in &input.views {
        let mut p = vec![0.0; v.camera.num_params()];
        v.camera.params(&mut p);
        p.into_iter().for_each(|x| hash.write_f64(x));
        hash.write_f64(v.camera.width() as f64);
        hash.write_f64(v.camera.height() as f64);
        v.cam_from_world
            .rotation
            .coords
            .iter()
            .for_each(|&x| hash.write_f64(x));
        v.cam_from_world
            .translation
            .iter()
            .for_each(|&x| hash.write_f64(x));
    }
    for p in &input.points {
        p.position.iter().for_each(|&x| hash.write_f64(x));
        p.views.iter().for_each(|&x| hash.write_f64(x as f64));
    }
    hash.hex()
}
