//! Train/test splits, exactly as RegNeRF (and so EdgeNeRF) defines them.
//!
//! * LLFF: test = every 8th image (`index % 8 == 0`); train = the other images, or with
//!   `k` views the images at `round(linspace(0, n_rest - 1, k))` of that list.
//! * DTU (pixelNeRF split): train = the first `k` of [`DTU_TRAIN_VIEWS`]; test = every
//!   view that is neither in [`DTU_TRAIN_VIEWS`] (all nine, whatever `k`) nor in
//!   [`DTU_EXCLUDED_VIEWS`]. Without `k` the train set is all nine ids (which is every
//!   view that is neither test nor excluded).
//! * Any list (Blender's `transforms_train.json`): [`linspace_indices`].
//!
//! `round` is Python's / NumPy's round-half-to-even. Invariants: `train` and `test` are
//! disjoint, sorted or in protocol order as documented, and index `views` directly.

/// Indices into `Scene::views`.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Split {
    pub train: Vec<usize>,
    pub test: Vec<usize>,
}

impl Split {
    /// The views of `0..n_views` in neither `train` nor `test`, in index order: a
    /// validation set for choosing settings without looking at the test views (DTU's
    /// excluded and unused protocol views, the training-side views a sparse run leaves
    /// out).
    pub fn unused(&self, n_views: usize) -> Vec<usize> {
        (0..n_views).filter(|i| !self.train.contains(i) && !self.test.contains(i)).collect()
    }
}

/// DTU training view ids in protocol order (pixelNeRF / RegNeRF); `k` views = first `k`.
pub const DTU_TRAIN_VIEWS: [usize; 9] = [25, 22, 28, 40, 44, 48, 0, 8, 13];

/// DTU view ids never used for testing (RegNeRF).
pub const DTU_EXCLUDED_VIEWS: [usize; 15] = [3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 36, 37, 38, 39];

/// Every `LLFF_HOLD`-th LLFF image is a test image.
pub const LLFF_HOLD: usize = 8;

/// `round(linspace(0, n - 1, k))`: `k` indices spread evenly over `0..n`, first and last
/// included. Distinct whenever `k <= n`. `k == 1` gives `[0]`.
pub fn linspace_indices(n: usize, k: usize) -> Vec<usize> {
    if k == 0 || n == 0 {
        return Vec::new();
    }
    if k == 1 {
        return vec![0];
    }
    let step = (n - 1) as f64 / (k - 1) as f64;
    (0..k)
        .map(|i| {
            if i == k - 1 {
                n - 1
            } else {
                (i as f64 * step).round_ties_even() as usize
            }
        })
        .collect()
}

/// Checks a requested view count against what a split can offer.
fn check_views(k: usize, available: usize) -> Result<(), String> {
    if k == 0 {
        return Err("0 training views requested; ask for at least 1".into());
    }
    if k > available {
        return Err(format!(
            "{k} training views requested but only {available} are available; ask for at most {available}"
        ));
    }
    Ok(())
}

/// The LLFF split of `n` images with `views` training views (`None` = all non-test).
/// Errors (a message) when `views` is 0 or exceeds the number of non-test images.
pub fn llff_split(n: usize, views: Option<usize>) -> Result<Split, String> {
    let test: Vec<usize> = (0..n).filter(|i| i % LLFF_HOLD == 0).collect();
    let rest: Vec<usize> = (0..n).filter(|i| i % LLFF_HOLD != 0).collect();
    let train = match views {
        None => rest,
        Some(k) => {
            check_views(k, rest.len())?;
            linspace_indices(rest.len(), k)
                .into_iter()
                .map(|i| rest[i])
                .collect()
        }
    };
    Ok(Split { train, test })
}

/// The DTU split of `n` views (ids `0..n`) with `views` training views (`None` = all 9).
pub fn dtu_split(n: usize, views: Option<usize>) -> Result<Split, String> {
    let k = views.unwrap_or(DTU_TRAIN_VIEWS.len());
    check_views(k, DTU_TRAIN_VIEWS.len())?;
    let train = DTU_TRAIN_VIEWS[..k].to_vec();
    if let Some(&id) = train.iter().find(|&&id| id >= n) {
        return Err(format!(
            "the DTU protocol trains on view {id} but the scan has only {n} views (ids 0..{n}); use fewer views"
        ));
    }
    let test = (0..n)
        .filter(|i| !DTU_TRAIN_VIEWS.contains(i) && !DTU_EXCLUDED_VIEWS.contains(i))
        .collect();
    Ok(Split { train, test })
}

/// Any list of `n` training items (Blender): all of them, or `k` by [`linspace_indices`].
pub fn subset_split(n: usize, views: Option<usize>) -> Result<Vec<usize>, String> {
    match views {
        None => Ok((0..n).collect()),
        Some(k) => {
            check_views(k, n)?;
            Ok(linspace_indices(n, k))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unused_views_are_dtus_excluded_and_unused_protocol_views() {
        let nine = dtu_split(49, Some(9)).unwrap();
        assert_eq!(nine.unused(49), DTU_EXCLUDED_VIEWS.to_vec());
        let three = dtu_split(49, Some(3)).unwrap();
        let mut expected: Vec<usize> = DTU_EXCLUDED_VIEWS.iter().chain(&DTU_TRAIN_VIEWS[3..]).copied().collect();
        expected.sort();
        assert_eq!(three.unused(49), expected);
        let fern = llff_split(20, Some(3)).unwrap();
        assert_eq!(fern.unused(20), vec![2, 3, 4, 5, 6, 7, 9, 11, 12, 13, 14, 15, 17, 18]);
    }

    #[test]
    fn linspace_matches_numpy() {
        // np.round(np.linspace(0, 16, 3)) = [0, 8, 16]; (0, 9, 4) = [0, 3, 6, 9];
        // (0, 5, 4) = [0, 1.667, 3.333, 5] -> [0, 2, 3, 5]; (0, 3, 3) = [0, 1.5, 3] -> [0, 2, 3].
        assert_eq!(linspace_indices(17, 3), vec![0, 8, 16]);
        assert_eq!(linspace_indices(10, 4), vec![0, 3, 6, 9]);
        assert_eq!(linspace_indices(6, 4), vec![0, 2, 3, 5]);
        assert_eq!(linspace_indices(4, 3), vec![0, 2, 3]);
        // Half to even: linspace(0, 5, 3) = [0, 2.5, 5] -> [0, 2, 5].
        assert_eq!(linspace_indices(6, 3), vec![0, 2, 5]);
        assert_eq!(linspace_indices(5, 1), vec![0]);
        assert_eq!(linspace_indices(5, 5), vec![0, 1, 2, 3, 4]);
    }

    #[test]
    fn llff_fern_protocol() {
        let s = llff_split(20, Some(3)).unwrap();
        assert_eq!(s.train, vec![1, 10, 19]);
        assert_eq!(s.test, vec![0, 8, 16]);
        assert_eq!(llff_split(20, None).unwrap().train.len(), 17);
        assert!(llff_split(20, Some(18)).is_err());
        assert!(llff_split(20, Some(0)).is_err());
    }

    #[test]
    fn dtu_protocol() {
        let s = dtu_split(49, Some(3)).unwrap();
        assert_eq!(s.train, vec![25, 22, 28]);
        assert_eq!(s.test.len(), 49 - 9 - 15);
        assert!(
            s.test
                .iter()
                .all(|i| !DTU_TRAIN_VIEWS.contains(i) && !DTU_EXCLUDED_VIEWS.contains(i))
        );
        assert_eq!(dtu_split(49, None).unwrap().train, DTU_TRAIN_VIEWS.to_vec());
        assert!(dtu_split(49, Some(10)).is_err());
        assert!(dtu_split(20, Some(1)).is_err());
    }
}
