//! What the align stage orients: the tracks from the match files, the initial cameras, the
//! local frame, the priors, control and check points and natural points, and the stable
//! ground as a grid.

use super::*;

/// Cells of the stable-ground grid along the longer side of the stable areas' extent (0.3 m on
/// a 300 m site): finer than the areas are drawn, coarser than a tie point is placed.
const STABLE_CELLS_PER_SIDE: f64 = 1000.0;

/// The stable areas as a grid in the block's local frame, when `inter_epoch_ties = "stable"`
/// and the project has some.
pub(super) fn stable_ground(
    project: &Project,
    frame: &LocalFrame,
) -> Result<Option<StableGround>, ProjectError> {
    if project.config.align.inter_epoch_ties == InterEpochTies::All
        || project.stable_areas.is_empty()
    {
        return Ok(None);
    }
    let polygons: Vec<&timesift_io::wkt::Polygon> = project
        .stable_areas
        .iter()
        .flat_map(|a| &a.polygons)
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in polygons.iter().flat_map(|p| &p.exterior) {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    if !(extent > 0.0) {
        return Err(stage_error(
            "the stable areas enclose no ground: inter_epoch_ties = \"stable\" needs polygons \
             with an area (or set it to \"all\")"
                .into(),
        ));
    }
    let cell = extent / STABLE_CELLS_PER_SIDE;
    let width = ((hi[0] - lo[0]) / cell).ceil().max(1.0) as usize;
    let height = ((hi[1] - lo[1]) / cell).ceil().max(1.0) as usize;
    let (ox, oy) = (frame.origin.x, frame.origin.y);
    let ground = StableGround::rasterise([lo[0] - ox, lo[1] - oy], cell, width, height, |x, y| {
        on_stable_area(project, x + ox, y + oy)
    })
    .map_err(|e| stage_error(e.to_string()))?;
    tracing::info!(
        cell,
        stable = ground.stable_fraction(),
        "inter-epoch ties only on the stable areas"
    );
    Ok(Some(ground))
}

/// Keypoints of every image, tracks over every verified pair, initial cameras per group.
pub(super) fn load_input(
    project: &Project,
    source: &ImageSource,
) -> Result<SfmInput, ProjectError> {
    let n = project.images.len();
    let keypoints = (0..n)
        .into_par_iter()
        .map(|i| {
            let path = project.layout().feature_file(i);
            read_features(&path)
                .map(|(k, _)| k.iter().map(|k| Vector2::new(k.x, k.y)).collect::<Vec<_>>())
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error(format!("{e} (run the features and match stages first)")))?;
    let pairs = match_files(&project.layout().matches_dir())?;
    if pairs.is_empty() {
        return Err(stage_error(format!(
            "{}: no match files (run the match stage first)",
            project.layout().matches_dir().display()
        )));
    }
    let verified = pairs
        .par_iter()
        .map(|(a, b, path)| {
            read_matches(path).map(|matches| PairMatches {
                a: ImageId::from(*a),
                b: ImageId::from(*b),
                matches,
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error(e.to_string()))?;
    let verified: Vec<PairMatches> = verified
        .into_iter()
        .filter(|p| !p.matches.is_empty() && p.a.index() < n && p.b.index() < n)
        .collect();
    let counts: Vec<usize> = keypoints.iter().map(Vec::len).collect();
    let tracks = build_tracks(&counts, &verified).map_err(|e| stage_error(e.to_string()))?;
    // One camera per group, from the first image of the group's first epoch.
    let mut group_index: BTreeMap<String, usize> = BTreeMap::new();
    let mut cameras = Vec::new();
    let mut focal = Vec::new();
    let mut group_of_epoch = Vec::new();
    for epoch in &project.epochs {
        let g = match group_index.get(&epoch.camera_group) {
            Some(&g) => g,
            None => {
                let first =
                    epoch.images.first().copied().ok_or_else(|| {
                        stage_error(format!("epoch \"{}\" has no image", epoch.name))
                    })?;
                let given = project.calibrations.get(&epoch.camera_group);
                let size = source.dimensions(project, first.index())?;
                let (camera, focal_source) =
                    initial_camera(&project.image_path(first), size, given)?;
                cameras.push(camera);
                focal.push(focal_source);
                group_index.insert(epoch.camera_group.clone(), cameras.len() - 1);
                cameras.len() - 1
            }
        };
        group_of_epoch.push(g);
    }
    check_one_size_per_group(project, source, &cameras, &group_of_epoch)?;
    let images = project
        .images
        .iter()
        .zip(keypoints)
        .map(|(im, keypoints)| SfmImage {
            group: group_of_epoch[im.epoch.index()],
            keypoints,
        })
        .collect();
    Ok(SfmInput {
        cameras,
        images,
        tracks: tracks.tracks,
        focal,
    })
}

/// Refuses a camera group whose images differ in size: one group is one set of intrinsics, and
/// an image of another size read through them has the wrong principal point and focal length in
/// pixels (the block absorbs it, bent).
fn check_one_size_per_group(
    project: &Project,
    source: &ImageSource,
    cameras: &[Camera],
    group_of_epoch: &[usize],
) -> Result<(), ProjectError> {
    let sizes: Vec<Result<(u32, u32), ProjectError>> = (0..project.images.len())
        .into_par_iter()
        .map(|i| source.dimensions(project, i))
        .collect();
    for (i, size) in sizes.into_iter().enumerate() {
        let (w, h) = size?;
        let epoch = &project.epochs[project.images[i].epoch.index()];
        let camera = &cameras[group_of_epoch[project.images[i].epoch.index()]];
        let expected = (camera.width(), camera.height());
        if (w, h) == expected {
            continue;
        }
        let first = project
            .epochs
            .iter()
            .filter(|e| e.camera_group == epoch.camera_group)
            .find_map(|e| e.images.first())
            .map_or_else(String::new, |f| project.images[f.index()].name.clone());
        return Err(stage_error(format!(
            "camera group \"{}\": {} is {w}×{h} pixels, the group's first image {first} {}×{}{}: \
             one camera group is one sensor at one resolution; give images of another size an \
             epoch or `[[camera]]` group of their own, or export every image at one size",
            epoch.camera_group,
            project.images[i].name,
            expected.0,
            expected.1,
            if (h, w) == expected {
                " (rotated: export it unrotated)"
            } else {
                ""
            },
        )));
    }
    Ok(())
}

/// The camera groups in the order of the input's cameras: as their first epochs come.
pub(super) fn group_names(project: &Project) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for epoch in &project.epochs {
        if !names.contains(&epoch.camera_group) {
            names.push(epoch.camera_group.clone());
        }
    }
    names
}

/// `work/matches/<a>_<b>.match` files, sorted.
fn match_files(dir: &Path) -> Result<Vec<(usize, usize, PathBuf)>, ProjectError> {
    let entries = std::fs::read_dir(dir).map_err(|e| {
        stage_error(format!(
            "{}: {e} (run the match stage first)",
            dir.display()
        ))
    })?;
    let mut files = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if let Some((a, b)) = Layout::match_file_pair(&path) {
            files.push((a, b, path));
        }
    }
    files.sort();
    Ok(files)
}

/// A distortion-free `brown` camera of the image's size as the stages see it (a scan: its
/// camera's frame) with the given focal length and principal point (a certificate's), the EXIF
/// focal length (known), or the default focal length (a guess).
pub(super) fn initial_camera(
    path: &Path,
    (w, h): (u32, u32),
    given: Option<&GivenFocal>,
) -> Result<(Camera, FocalSource), ProjectError> {
    let (f, source) = match given {
        Some(g) if g.adjust => (g.focal_px, FocalSource::Nominal),
        Some(g) => (g.focal_px, FocalSource::Calibrated),
        None => match timesift_io::exif::read_exif(path)
            .ok()
            .and_then(|e| e.focal_length_px(w, h))
        {
            Some(f) => (f, FocalSource::Nominal),
            None => (DEFAULT_FOCAL_FACTOR * w.max(h) as f64, FocalSource::Guessed),
        },
    };
    let mut camera =
        BrownCamera::new(w, h, f).map_err(|e| stage_error(format!("{}: {e}", path.display())))?;
    if let Some((cx, cy)) = given.and_then(|g| g.principal_point) {
        camera.cx = cx;
        camera.cy = cy;
    }
    if let Some([k1, k2, k3]) = given.and_then(|g| g.radial) {
        (camera.k1, camera.k2, camera.k3) = (k1, k2, k3);
    }
    Ok((Camera::Brown(camera), source))
}

/// The local frame: project CRS minus `origin`.
pub(super) struct LocalFrame {
    pub(super) origin: Vector3<f64>,
    pub(super) priors: Vec<Option<crate::project::CameraPrior>>,
}

impl LocalFrame {
    pub(super) fn of(project: &Project) -> Result<Self, ProjectError> {
        let priors = project.camera_priors()?;
        super::checks::check_ground_points_near_priors(project, &priors)?;
        let positions: Vec<Vector3<f64>> = priors
            .iter()
            .flatten()
            .map(|p| p.position)
            .chain(project.gcps.iter().map(|g| g.position))
            .collect();
        let origin = if positions.is_empty() {
            Vector3::zeros()
        } else {
            let mean = positions.iter().sum::<Vector3<f64>>() / positions.len() as f64;
            mean.map(f64::round)
        };
        Ok(LocalFrame { origin, priors })
    }

    /// `cam_from_world` in the project CRS from `cam_from_local`.
    pub(super) fn world_pose(&self, pose: &Pose) -> Pose {
        Pose::new(
            pose.rotation,
            pose.translation - pose.rotation * self.origin,
        )
    }
}

/// GNSS priors, control points (markers of the reference epoch only unless
/// `gcps_in_all_epochs`) and check points, in the local frame; and the natural stable points
/// (their markers in every epoch).
pub(super) fn ground_input(
    project: &Project,
    frame: &LocalFrame,
    source: &ImageSource,
) -> Result<(GeoreferenceInput, Vec<NaturalPoint>), ProjectError> {
    let index_of: BTreeMap<&str, usize> = project
        .images
        .iter()
        .enumerate()
        .map(|(i, im)| (im.name.as_str(), i))
        .collect();
    let reference = project.reference_epoch;
    let markers_of = |name: &str, control: bool| -> Vec<Marker> {
        project
            .markers
            .iter()
            .filter(|m| m.name == name)
            .filter_map(|m| {
                let image = *index_of.get(m.image.as_str())?;
                let in_reference = project.images[image].epoch == reference;
                (!control || in_reference || project.config.align.gcps_in_all_epochs).then_some(
                    Marker {
                        image,
                        // Measured on the file: a scan's marker moves to the camera's frame.
                        pixel: source.stage_pixel(image, &m.pixel),
                    },
                )
            })
            .collect()
    };
    let mut points = Vec::new();
    for (list, check) in [(&project.gcps, false), (&project.checkpoints, true)] {
        for g in list {
            let (sxy, sz) = g.sigma.unwrap_or(DEFAULT_GCP_SIGMA);
            points.push(GroundPoint {
                name: g.name.clone(),
                position: g.position - frame.origin,
                sigma_xy: sxy,
                sigma_z: sz,
                check,
                markers: markers_of(&g.name, !check),
                marker_sigma_px: None,
            });
        }
    }
    // One GNSS offset per epoch with priors, its prior σ the epoch's mean stated accuracy.
    let mut prior_offsets = Vec::new();
    let mut offset_of_epoch = vec![None; project.epochs.len()];
    if project.config.gnss.offsets == GnssOffsets::Epoch {
        for (e, epoch) in project.epochs.iter().enumerate() {
            let stated: Vec<(f64, f64)> = epoch
                .images
                .iter()
                .filter_map(|i| frame.priors[i.index()].as_ref().map(|p| (p.sxy, p.sz)))
                .collect();
            if stated.is_empty() {
                continue;
            }
            let n = stated.len() as f64;
            offset_of_epoch[e] = Some(prior_offsets.len());
            prior_offsets.push(OffsetPrior {
                name: epoch.name.clone(),
                sigma_xy: stated.iter().map(|s| s.0).sum::<f64>() / n,
                sigma_z: stated.iter().map(|s| s.1).sum::<f64>() / n,
            });
        }
    }
    let centre_priors = frame
        .priors
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            p.as_ref().map(|p| CentrePrior {
                image: i,
                position: p.position - frame.origin,
                sigma_xy: p.sxy,
                sigma_z: p.sz,
                offset: offset_of_epoch[project.images[i].epoch.index()],
            })
        })
        .collect();
    let natural_points = project
        .stable_points
        .iter()
        .map(|s| NaturalPoint {
            name: s.name.clone(),
            stability: s.sigma,
            markers: markers_of(&s.name, false),
        })
        .collect();
    Ok((
        GeoreferenceInput {
            centre_priors,
            prior_offsets,
            points,
            marker_sigma_px: project.config.align.marker_accuracy_px,
            rigid_sets: (0..project.epochs.len())
                .map(|e| {
                    let images = project.images.iter().enumerate();
                    images
                        .filter(|(_, im)| im.epoch.index() == e)
                        .map(|(i, _)| i)
                        .collect()
                })
                .collect(),
            surface_heights: Vec::new(),
            reference_dem: None,
        },
        natural_points,
    ))
}

/// Whether (x, y), in the project's CRS, lies in one of the stable areas (`stable.csv`).
pub(super) fn on_stable_area(project: &Project, x: f64, y: f64) -> bool {
    project
        .stable_areas
        .iter()
        .flat_map(|a| &a.polygons)
        .any(|polygon| polygon.contains(x, y))
}
