//! Many images at once: decoded, extracted and handed to the caller one by one, in parallel, so
//! that no more images are in memory than there are threads.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::{FeatureError, FeatureExtractor, Features, GreyImage};

/// Extracts the features of every image in `paths` in parallel and passes each result to `sink`
/// (with the image's index) as soon as it is ready; the image is dropped before the next one is
/// decoded on that thread. Errors are reported per image, they do not stop the others.
pub fn extract_files<S>(paths: &[PathBuf], extractor: &dyn FeatureExtractor, sink: S)
where
    S: Fn(usize, &Path, Result<Features, FeatureError>) + Sync,
{
    paths.par_iter().enumerate().for_each(|(i, path)| {
        sink(i, path, extract_file(path, extractor));
    });
}

/// Decodes one image as grey and extracts its features.
pub fn extract_file(
    path: &Path,
    extractor: &dyn FeatureExtractor,
) -> Result<Features, FeatureError> {
    let image = timesift_io::image::read_grey(path)?;
    let grey = GreyImage::from_io(&image)?;
    extractor.extract(&grey, None)
}
