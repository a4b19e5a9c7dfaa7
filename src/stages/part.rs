//! A unit's share of a step's list: `--part i/n`.

use std::fmt;
use std::str::FromStr;

/// Unit `index` (1-based) of `count`: `--part 3/10` on the command line, Slurm's
/// `SLURM_ARRAY_TASK_ID` in a job array.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Part {
    /// 1 ..= count.
    pub index: usize,
    /// How many units the step was split into.
    pub count: usize,
}

impl Part {
    /// The whole list as one unit (what the local executor runs).
    pub const WHOLE: Part = Part { index: 1, count: 1 };

    /// The part, or an error naming what is wrong.
    pub fn new(index: usize, count: usize) -> Result<Part, String> {
        if count == 0 || index == 0 || index > count {
            return Err(format!(
                "part {index}/{count}: expected 1 <= i <= n with n >= 1"
            ));
        }
        Ok(Part { index, count })
    }

    /// The indices of a list of `len` items this unit takes: a contiguous share, sizes
    /// differing by at most one, so that every item is in exactly one unit.
    pub fn range(&self, len: usize) -> std::ops::Range<usize> {
        let i = self.index - 1;
        (len * i / self.count)..(len * (i + 1) / self.count)
    }
}

impl fmt::Display for Part {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Part {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| format!("part \"{s}\": expected i/n, e.g. 3/10"))?;
        let parse = |v: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|_| format!("part \"{s}\": expected i/n with whole numbers"))
        };
        Part::new(parse(i)?, parse(n)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_cover_a_list_exactly_once_in_near_equal_shares() {
        for len in [0usize, 1, 7, 100, 101] {
            for count in 1..=12 {
                let mut seen = vec![0u32; len];
                let mut sizes = Vec::new();
                for index in 1..=count {
                    let r = Part::new(index, count).unwrap().range(len);
                    sizes.push(r.len());
                    for i in r {
                        seen[i] += 1;
                    }
                }
                assert!(seen.iter().all(|&s| s == 1), "len {len} count {count}");
                let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
                assert!(hi - lo <= 1, "len {len} count {count}: {sizes:?}");
            }
        }
    }

    #[test]
    fn parts_parse_from_the_command_line_and_reject_what_is_not_one() {
        assert_eq!(
            "3/10".parse::<Part>(),
            Ok(Part {
                index: 3,
                count: 10
            })
        );
        for bad in ["0/3", "4/3", "1/0", "3", "a/b", "-1/2"] {
            let e = bad.parse::<Part>().unwrap_err();
            assert!(e.contains("part"), "{bad}: {e}");
        }
    }
}
