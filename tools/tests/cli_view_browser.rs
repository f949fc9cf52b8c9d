//! `edgenerf view` in a real browser: headless Chromium driven through chromedriver
//! (WebDriver's JSON over HTTP on loopback) against the viewer of a 30-step run of the
//! committed `creases` scene. The page loads with no console errors, a drag changes the
//! frame, the depth mode shows a depth map (turbo colours), and the frame the page shows
//! at a test camera equals `edgenerf render` of that view within 1/255.
//!
//! Needs Debian's `chromium` and `chromium-driver` (`tools/run test` installs them);
//! skipped with a message when they are missing, unless EDGENERF_REQUIRE_CHROMIUM=1
//! (set by CI's `.ci/run`) makes that a failure.

mod common;
mod view_support;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use serde_json::{Value, json};
use view_support::{Viewer, max_diff, png_rgb, request, tiny_run, wait_for};

/// The first of `names` found on PATH or in the usual Debian places.
fn find(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    let dirs: Vec<PathBuf> = std::env::split_paths(&path).chain([PathBuf::from("/usr/bin"), PathBuf::from("/usr/lib/chromium")]).collect();
    names.iter().flat_map(|n| dirs.iter().map(move |d| d.join(n))).find(|p| p.is_file())
}

/// chromedriver on a free port, killed on drop.
struct Driver {
    child: Child,
    addr: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One WebDriver session.
struct Session {
    addr: String,
    id: String,
}

fn wd(addr: &str, method: &str, path: &str, body: Option<Value>) -> (u16, Value) {
    let body = body.map(|b| b.to_string());
    let r = request(addr, method, path, body.as_deref()).unwrap_or_else(|e| panic!("chromedriver {method} {path}: {e}"));
    let v: Value = serde_json::from_slice(&r.body).unwrap_or(Value::Null);
    (r.status, v.get("value").cloned().unwrap_or(Value::Null))
}

impl Session {
    fn call(&self, method: &str, path: &str, body: Value) -> Value {
        let (status, v) = wd(&self.addr, method, &format!("/session/{}{path}", self.id), Some(body));
        assert_eq!(status, 200, "WebDriver {method} {path}: {v}");
        v
    }
    fn js(&self, script: &str) -> Value {
        self.call("POST", "/execute/sync", json!({ "script": script, "args": [] }))
    }
    fn element(&self, css: &str) -> Value {
        let v = self.call("POST", "/element", json!({ "using": "css selector", "value": css }));
        let id = v["element-6066-11e4-a52e-4f735466cecf"].as_str().unwrap_or_else(|| panic!("no element {css}: {v}"));
        json!({ "element-6066-11e4-a52e-4f735466cecf": id })
    }
    fn click(&self, css: &str) {
        let e = self.element(css);
        let id = e["element-6066-11e4-a52e-4f735466cecf"].as_str().unwrap().to_string();
        self.call("POST", &format!("/element/{id}/click"), json!({}));
    }
    /// Waits until the page shows the full-resolution frame of its current camera and
    /// mode, after at least `frames` frames.
    fn wait_idle(&self, frames: u64) {
        wait_for(120, "the page to show its full-resolution frame", || {
            let s = self.js("return [document.body.dataset.state || '', +(document.body.dataset.frames || 0)];");
            (s[0] == "idle" && s[1].as_u64().unwrap_or(0) >= frames).then_some(())
        });
    }
    fn frames(&self) -> u64 {
        self.js("return +(document.body.dataset.frames || 0);").as_u64().unwrap()
    }
    /// The pixels of the frame on the page, at its own size, as RGB8.
    fn frame_pixels(&self) -> image::RgbImage {
        let v = self.js(
            "const img = document.getElementById('frame');
             const c = document.createElement('canvas'); c.width = img.naturalWidth; c.height = img.naturalHeight;
             const g = c.getContext('2d'); g.drawImage(img, 0, 0);
             const d = g.getImageData(0, 0, c.width, c.height).data;
             const rgb = []; for (let i = 0; i < d.length; i += 4) rgb.push(d[i], d[i + 1], d[i + 2]);
             return [c.width, c.height, rgb];",
        );
        let (w, h) = (v[0].as_u64().unwrap() as u32, v[1].as_u64().unwrap() as u32);
        let px: Vec<u8> = v[2].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u8).collect();
        image::RgbImage::from_raw(w, h, px).unwrap()
    }
    /// The browser console's entries (chromedriver's log endpoint).
    fn console(&self) -> Vec<Value> {
        self.call("POST", "/se/log", json!({ "type": "browser" })).as_array().cloned().unwrap_or_default()
    }
}

fn start_session(driver: &Driver, chromium: &Path, profile: &Path) -> Session {
    let args = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        "--window-size=1280,900",
        &format!("--user-data-dir={}", profile.display()),
    ];
    let caps = json!({ "capabilities": { "alwaysMatch": {
        "browserName": "chrome",
        "goog:chromeOptions": { "binary": chromium, "args": args },
        "goog:loggingPrefs": { "browser": "ALL" },
    }}});
    let (status, v) = wd(&driver.addr, "POST", "/session", Some(caps));
    assert_eq!(status, 200, "creating a Chromium session: {v}");
    Session { addr: driver.addr.clone(), id: v["sessionId"].as_str().unwrap().to_string() }
}

/// Whether every pixel is black (no depth) or close to a colour of the depth map.
fn depth_coloured_fraction(img: &image::RgbImage) -> (f64, f64) {
    let turbo: Vec<[f32; 3]> = (0..=512).map(|i| edgenerf::viz::turbo(i as f32 / 512.0)).collect();
    let (mut coloured, mut on_map) = (0usize, 0usize);
    for p in img.pixels() {
        let c = [p[0] as f32 / 255.0, p[1] as f32 / 255.0, p[2] as f32 / 255.0];
        if c.iter().all(|&x| x == 0.0) {
            continue;
        }
        coloured += 1;
        let d = turbo.iter().map(|t| (0..3).map(|k| (t[k] - c[k]).abs()).fold(0.0, f32::max)).fold(f32::MAX, f32::min);
        if d <= 3.0 / 255.0 {
            on_map += 1;
        }
    }
    let n = (img.width() * img.height()) as f64;
    (coloured as f64 / n, on_map as f64 / coloured.max(1) as f64)
}

#[test]
fn view_in_headless_chromium() {
    let (Some(chromium), Some(chromedriver)) = (find(&["chromium", "chromium-browser"]), find(&["chromedriver"])) else {
        let msg = "chromium or chromedriver missing: 'apt-get install chromium chromium-driver' (tools/run test does) enables this test";
        if std::env::var("EDGENERF_REQUIRE_CHROMIUM").is_ok_and(|v| v == "1") {
            panic!("{msg} (EDGENERF_REQUIRE_CHROMIUM=1)");
        }
        eprintln!("skipped: {msg}");
        return;
    };
    // Debian's /usr/bin/chromium is a wrapper script; the browser itself is beside it.
    let chromium = if Path::new("/usr/lib/chromium/chromium").is_file() { PathBuf::from("/usr/lib/chromium/chromium") } else { chromium };

    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    tiny_run(&run, 30);
    let out = tmp.path().join("renders");
    let o = common::edgenerf(&["render", run.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "render failed:\n{}", common::text(&o));
    let mut viewer = Viewer::start(&run, &[]);

    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let child = Command::new(&chromedriver)
        .args([format!("--port={port}"), "--allowed-ips=127.0.0.1".into()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromedriver");
    let driver = Driver { child, addr: format!("127.0.0.1:{port}") };
    wait_for(60, "chromedriver to answer", || {
        request(&driver.addr, "GET", "/status", None).ok().filter(|r| r.status == 200).map(|_| ())
    });
    let session = start_session(&driver, &chromium, &tmp.path().join("profile"));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let s = &session;
        s.call("POST", "/url", json!({ "url": format!("http://{}/", viewer.addr) }));
        s.wait_idle(1);
        let first = s.frame_pixels();
        let info = view_support::get(&viewer.addr, "/api/info").json();
        assert_eq!(first.dimensions(), (info["width"].as_u64().unwrap() as u32, info["height"].as_u64().unwrap() as u32));

        // A drag on the frame orbits the camera: a different frame.
        let frames = s.frames();
        let vp = s.element("#viewport");
        let mut steps = vec![json!({ "type": "pointerMove", "duration": 0, "origin": vp, "x": 0, "y": 0 }), json!({ "type": "pointerDown", "button": 0 })];
        for _ in 0..6 {
            steps.push(json!({ "type": "pointerMove", "duration": 50, "origin": "pointer", "x": 25, "y": 4 }));
        }
        steps.push(json!({ "type": "pointerUp", "button": 0 }));
        s.call("POST", "/actions", json!({ "actions": [{ "type": "pointer", "id": "mouse", "parameters": { "pointerType": "mouse" }, "actions": steps }] }));
        s.wait_idle(frames + 1);
        let dragged = s.frame_pixels();
        let changed = first.pixels().zip(dragged.pixels()).filter(|(a, b)| a.0.iter().zip(b.0.iter()).any(|(x, y)| x.abs_diff(*y) > 8)).count();
        assert!(changed > (first.width() * first.height() / 20) as usize, "a drag changed only {changed} pixels of the frame");

        // The depth mode shows a depth map: turbo colours where there is surface.
        let frames = s.frames();
        s.click("#modes [data-mode=depth]");
        s.wait_idle(frames + 1);
        assert_eq!(s.js("return document.body.dataset.mode;"), "depth");
        let depth = s.frame_pixels();
        let (coloured, on_map) = depth_coloured_fraction(&depth);
        assert!(coloured > 0.05, "the depth frame is black ({coloured:.3} coloured)");
        assert!(on_map > 0.98, "only {on_map:.3} of the depth frame's pixels are depth-map colours");
        let (_, rgb_on_map) = depth_coloured_fraction(&dragged);
        assert!(rgb_on_map < 0.9, "the RGB frame looked like a depth map too ({rgb_on_map:.3}): the check proves nothing");

        // Back to RGB, jump to a test view: the page shows exactly `edgenerf render`'s image.
        let frames = s.frames();
        s.click("#modes [data-mode=rgb]");
        s.wait_idle(frames + 1);
        let t = info["views"].as_array().unwrap().iter().find(|v| v["split"] == "test").unwrap().clone();
        let frames = s.frames();
        s.click(&format!("#views button[data-view=\"{}\"]", t["index"]));
        s.wait_idle(frames + 1);
        let want = png_rgb(&std::fs::read(out.join(format!("{}_rgb.png", t["name"].as_str().unwrap()))).unwrap());
        let shown = s.frame_pixels();
        assert!(max_diff(&shown, &want) <= 1, "the page's frame at test view {} differs from render's by {}/255", t["name"], max_diff(&shown, &want));
        // The side panel filled in: metrics and its images loaded.
        let t = std::time::Instant::now();
        loop {
            let v = s.js(
                "const imgs = [...document.querySelectorAll('#panel-grid img')];
                 return [document.getElementById('panel-metrics').textContent, imgs.length,
                         imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)];",
            );
            if v[0].as_str().unwrap_or("").contains("PSNR") && v[1].as_u64().unwrap_or(0) >= 6 && v[2].as_array().is_some_and(|a| a.is_empty()) {
                break;
            }
            if t.elapsed().as_secs() >= 120 {
                let entries = s.js("return performance.getEntriesByType('resource').map(e => [e.name, e.responseStatus, Math.round(e.startTime), Math.round(e.duration)]);");
                let direct: Vec<String> = v[2].as_array().unwrap().iter().map(|u| {
                    let path = u.as_str().unwrap().splitn(4, '/').nth(3).unwrap_or("");
                    let r = view_support::get(&viewer.addr, &format!("/{path}"));
                    format!("{path}: {} {} bytes", r.status, r.body.len())
                }).collect();
                panic!("the view panel did not fill in 120 s (metrics, images, those not loaded): {v}\nresources: {entries}\ndirect: {direct:?}");
            }
            std::thread::sleep(std::time::Duration::from_millis(100));
        }

        // No console errors or warnings from the page through all of it.
        let bad: Vec<Value> = s.console().into_iter().filter(|e| e["level"] == "SEVERE" || e["level"] == "WARNING").collect();
        assert!(bad.is_empty(), "console errors: {bad:?}");
    }));
    let _ = wd(&driver.addr, "DELETE", &format!("/session/{}", session.id), None);
    assert!(viewer.alive(), "the viewer died");
    if let Err(e) = result {
        std::panic::resume_unwind(e);
    }
}
