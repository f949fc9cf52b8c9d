//! `edgenerf train` with RegNeRF's options: `--regnerf-depth-tv` and
//! `--anneal-sample-space` train, land in the effective config, and log the depth TV
//! term (appended `loss_tv` / `lambda_tv` columns of `log.csv`).

mod common;

use common::{read_log, text, train_creases_3v};

#[test]
fn regnerf_flags_train_and_log_the_depth_tv_term() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("regnerf");
    let o = train_creases_3v(
        &dir,
        3,
        &["--no-depth-reg", "--no-normal-reg", "--regnerf-depth-tv", "--anneal-sample-space", "--set", "regnerf.patches_per_step=4"],
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let (header, rows) = read_log(&dir);
    let at = header.iter().position(|h| *h == "elapsed_s").expect("elapsed_s column");
    assert_eq!(&header[at..at + 3], ["elapsed_s", "loss_tv", "lambda_tv"], "new columns appended");
    assert_eq!(rows.len(), 3);
    let log = format!("{header:?}\n{rows:?}");
    let col = |k: &str| header.iter().position(|h| *h == k).unwrap();
    for (s, r) in rows.iter().enumerate() {
        // RegNeRF's decaying weight 400 -> 0.1 over 512 steps, divided by 3 (module doc).
        let want = (400.0 * (1.0 - (s + 1) as f64 / 512.0) + 0.1 * (s + 1) as f64 / 512.0) / 3.0;
        assert!((r[col("lambda_tv")] - want).abs() < 1e-3 * want, "step {s}: lambda_tv {} vs {want}", r[col("lambda_tv")]);
        assert!(r[col("loss_tv")].is_finite() && r[col("loss_tv")] >= 0.0);
        assert_eq!((r[col("lambda_depth")], r[col("lambda_normal")]), (0.0, 0.0));
    }
    assert!(rows.iter().any(|r| r[col("loss_tv")] > 0.0), "the term is measured:\n{log}");
    let cfg: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("config.json")).unwrap()).unwrap();
    assert_eq!((cfg["regnerf"]["depth_tv"].as_bool(), cfg["regnerf"]["anneal"].as_bool()), (Some(true), Some(true)));
    assert_eq!(cfg["regnerf"]["patch_size"], 8);

    // Without the flags: no term, and the trailing columns read 0.
    let plain = out.path().join("plain");
    let o = train_creases_3v(&plain, 1, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let row = &read_log(&plain).1[0];
    assert_eq!([row[col("loss_tv")], row[col("lambda_tv")]], [0.0, 0.0]);
}
