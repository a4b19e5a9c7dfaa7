//! Depth maps on disk (`work/dense/<epoch>/`, EXR, one file per view and pass) and the maps of
//! the last passes kept in memory: a geometric pass reads every source's map of the pass
//! before, so without the cache each map was decoded again for every view it is a source of.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::Arc;

use timesift_dense::DepthMap;

use crate::ProjectError;

pub(super) fn write_map(path: &Path, map: &DepthMap) -> Result<(), ProjectError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| timesift_io::IoError::io(parent, e))?;
    }
    let channel = |k: usize| map.normal.iter().map(|n| n[k]).collect::<Vec<f32>>();
    let (nx, ny, nz) = (channel(0), channel(1), channel(2));
    let upsampled: Vec<f32> = map.upsampled.iter().map(|&u| f32::from(u)).collect();
    timesift_io::exr::write_f32_channels(
        path,
        map.width,
        map.height,
        &[
            ("depth", &map.depth),
            ("nx", &nx),
            ("ny", &ny),
            ("nz", &nz),
            ("cost", &map.cost),
            ("upsampled", &upsampled),
        ],
    )?;
    Ok(())
}

/// A map written by [`write_map`]; `None` when the file is missing or not such a map (it is then
/// recomputed).
pub(super) fn read_map(path: &Path) -> Option<DepthMap> {
    let read = timesift_io::exr::read_f32_channels(path).ok()?;
    let (depth, nx, ny, nz, cost, upsampled) = (
        read.channel("depth")?,
        read.channel("nx")?,
        read.channel("ny")?,
        read.channel("nz")?,
        read.channel("cost")?,
        read.channel("upsampled")?,
    );
    Some(DepthMap {
        width: read.width,
        height: read.height,
        depth: depth.to_vec(),
        normal: (0..read.width * read.height)
            .map(|k| [nx[k], ny[k], nz[k]])
            .collect(),
        cost: cost.to_vec(),
        upsampled: upsampled.iter().map(|&u| u > 0.5).collect(),
    })
}

/// The most recently used maps, keyed by (pass, view), up to a budget of bytes.
pub(super) struct MapCache {
    budget: usize,
    bytes: usize,
    entries: VecDeque<((usize, usize), Arc<DepthMap>)>,
}

impl MapCache {
    /// An empty cache holding at most `budget` bytes of maps (at least the last one put).
    pub(super) fn new(budget: usize) -> MapCache {
        MapCache {
            budget,
            bytes: 0,
            entries: VecDeque::new(),
        }
    }

    /// The map of `view` in `pass`, if kept.
    pub(super) fn get(&mut self, pass: usize, view: usize) -> Option<Arc<DepthMap>> {
        let at = self.entries.iter().position(|(k, _)| *k == (pass, view))?;
        let entry = self.entries.remove(at)?;
        let map = entry.1.clone();
        self.entries.push_back(entry);
        Some(map)
    }

    /// The map of `view` in `pass`, from the cache or else read from `path` and kept: a map
    /// read back is a source or neighbour of the next views too. `None` when it is in neither.
    pub(super) fn get_or_read(
        &mut self,
        pass: usize,
        view: usize,
        path: &Path,
    ) -> Option<Arc<DepthMap>> {
        if let Some(map) = self.get(pass, view) {
            return Some(map);
        }
        let map = Arc::new(read_map(path)?);
        self.put(pass, view, map.clone());
        Some(map)
    }

    /// Keeps the map of `view` in `pass`, dropping the least recently used beyond the budget.
    pub(super) fn put(&mut self, pass: usize, view: usize, map: Arc<DepthMap>) {
        self.bytes += map_bytes(&map);
        self.entries.push_back(((pass, view), map));
        while self.bytes > self.budget && self.entries.len() > 1 {
            if let Some((_, old)) = self.entries.pop_front() {
                self.bytes -= map_bytes(&old);
            }
        }
    }
}

/// Memory of a map's channels.
fn map_bytes(map: &DepthMap) -> usize {
    map.depth.len() * (4 + 12 + 4 + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_keeps_the_most_recently_used_maps_within_its_budget() {
        let map = || Arc::new(DepthMap::empty(10, 10));
        // Each map is 100 pixels of 21 bytes: a budget of 5,000 bytes holds two, not three.
        let mut cache = MapCache::new(5_000);
        cache.put(0, 0, map());
        cache.put(0, 1, map());
        assert!(cache.get(0, 0).is_some());
        cache.put(0, 2, map());
        // (0, 1) was the least recently used.
        assert!(cache.get(0, 1).is_none());
        assert!(cache.get(0, 0).is_some() && cache.get(0, 2).is_some());
        assert!(cache.get(1, 0).is_none());
        // A map larger than the budget is still kept, alone.
        let mut small = MapCache::new(10);
        small.put(3, 4, map());
        small.put(3, 5, map());
        assert!(small.get(3, 4).is_none() && small.get(3, 5).is_some());
    }
}
