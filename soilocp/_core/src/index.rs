//! The vehicles of one step of a bank of N: distinct indices in [0, N), checked once for every bank
//! and binding.

use std::fmt::Debug;

/// The indices `idx` of one step's vehicles as `usize`; an error naming them unless they are
/// distinct and each in [0, n) (a negative index is out of range).
pub fn vehicles<T: Copy + Debug + TryInto<usize>>(idx: &[T], n: usize) -> Result<Vec<usize>, String> {
    let mut seen = vec![false; n];
    let mut out = Vec::with_capacity(idx.len());
    for &i in idx {
        match i.try_into() {
            Ok(g) if g < n && !std::mem::replace(&mut seen[g], true) => out.push(g),
            _ => return Err(format!("idx must be distinct vehicle indices in [0, {n}), got {idx:?}")),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distinct_and_in_range_or_named() {
        assert_eq!(vehicles(&[2i64, 0], 3).unwrap(), [2, 0]);
        assert_eq!(vehicles::<usize>(&[], 1).unwrap(), Vec::<usize>::new());
        for bad in [&[3i64][..], &[-1], &[1, 1]] {
            let e = vehicles(bad, 3).unwrap_err();
            assert!(
                e.starts_with("idx must be distinct vehicle indices in [0, 3), got ["),
                "{e}"
            );
        }
        assert!(vehicles(&[0usize, 0], 2).is_err());
    }
}
