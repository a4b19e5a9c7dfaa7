//! Seeded mutation of corpus inputs, for machines without a nightly toolchain: truncation at
//! every offset, bit flips, chunk replacement (from another input, random bytes, or the
//! boundary values that make header sizes lie), insertion and deletion. No coverage guides it;
//! inputs a reader accepted join the pool, so mutations build on inputs that got deep.

/// A small, fast, seeded generator (SplitMix64): runs repeat exactly for a seed.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator started from `seed`.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A number in `0..n` (`n` > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// Values that make a size, count or offset field lie: zero, one, the largest of each width,
/// one past a power of two, negative numbers.
const BOUNDARY_VALUES: [u64; 10] = [
    0,
    1,
    0x7f,
    0xff,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
    0x1_0000_0001,
    u64::MAX,
];

/// Which mutation made an input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mutation {
    /// Some bits flipped.
    BitFlips,
    /// A range replaced by the bytes of a range of another input.
    Splice,
    /// A range replaced by random bytes.
    RandomChunk,
    /// A little- or big-endian boundary value written over 1, 2, 4 or 8 bytes.
    BoundaryValue,
    /// A range removed.
    Deletion,
    /// A range of the input repeated.
    Duplication,
}

/// Mutates `input` into `out` (cleared first), drawing another input from `pool` for splices.
pub fn mutate(rng: &mut Rng, input: &[u8], pool: &[Vec<u8>], out: &mut Vec<u8>) -> Mutation {
    out.clear();
    out.extend_from_slice(input);
    if out.is_empty() {
        out.push(rng.next_u64() as u8);
        return Mutation::RandomChunk;
    }
    let n = out.len();
    let range = |rng: &mut Rng| {
        let start = rng.below(n);
        let len = 1 + rng.below((n - start).min(64));
        (start, len)
    };
    match rng.below(6) {
        0 => {
            for _ in 0..1 + rng.below(4) {
                let at = rng.below(n);
                out[at] ^= 1 << rng.below(8);
            }
            Mutation::BitFlips
        }
        1 if !pool.is_empty() => {
            let other = &pool[rng.below(pool.len())];
            if other.is_empty() {
                return mutate(rng, input, &[], out);
            }
            let (start, len) = range(rng);
            let from = rng.below(other.len());
            let piece = &other[from..(from + len).min(other.len())];
            out.splice(start..start + len, piece.iter().copied());
            Mutation::Splice
        }
        2 => {
            let (start, len) = range(rng);
            for b in &mut out[start..start + len] {
                *b = rng.next_u64() as u8;
            }
            Mutation::RandomChunk
        }
        3 | 1 => {
            let value = BOUNDARY_VALUES[rng.below(BOUNDARY_VALUES.len())];
            let width = [1, 2, 4, 8][rng.below(4)].min(n);
            let at = rng.below(n - width + 1);
            let bytes = if rng.below(2) == 0 {
                value.to_le_bytes()
            } else {
                value.to_be_bytes()
            };
            let picked = if bytes[0] == 0 && value != 0 {
                // Big-endian: the low bytes are the last ones.
                &bytes[8 - width..]
            } else {
                &bytes[..width]
            };
            out[at..at + width].copy_from_slice(picked);
            Mutation::BoundaryValue
        }
        4 => {
            let (start, len) = range(rng);
            out.drain(start..start + len);
            Mutation::Deletion
        }
        _ => {
            let (start, len) = range(rng);
            let piece: Vec<u8> = out[start..start + len].to_vec();
            let at = rng.below(n + 1);
            out.splice(at..at, piece);
            Mutation::Duplication
        }
    }
}

/// A short name for an input's content (FNV-1a, 64 bits, in hex): the file name it is kept under.
pub fn content_name(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutations_repeat_for_a_seed_and_change_the_input() {
        let input: Vec<u8> = (0..200u8).collect();
        let pool = vec![vec![7u8; 50]];
        let run = |seed| {
            let mut rng = Rng::new(seed);
            let mut out = Vec::new();
            (0..200)
                .map(|_| {
                    mutate(&mut rng, &input, &pool, &mut out);
                    out.clone()
                })
                .collect::<Vec<_>>()
        };
        let a = run(1);
        assert_eq!(a, run(1));
        assert_ne!(a, run(2));
        let changed = a.iter().filter(|m| **m != input).count();
        // A boundary value may rewrite bytes with what they held; every other mutation changes.
        assert!(
            changed >= 180,
            "{changed} of 200 mutants differ from the input"
        );
    }

    #[test]
    fn empty_inputs_grow() {
        let mut out = Vec::new();
        mutate(&mut Rng::new(3), &[], &[], &mut out);
        assert_eq!(out.len(), 1);
    }

    #[test]
    fn content_names_differ_for_different_bytes() {
        assert_ne!(content_name(b"a"), content_name(b"b"));
        assert_eq!(content_name(b"abc").len(), 16);
    }
}
