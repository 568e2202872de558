//! The station in a real browser: headless Chromium driven through WebDriver (chromedriver,
//! the fantoccini client) opens the page of a station replaying rendered frames through the
//! in-process device, waits until the Live panel shows points and the Surface panel a rotation
//! profile, presses Capture (twice) and Compare, and checks the session's files and that its
//! `analysis.json` (and `report.html`) are byte for byte what `deltaz analyse back` writes for
//! the same clouds. Screenshots of the page and each panel go to
//! `target/station-screenshots/`. Skips visibly without Chromium (CI installs it and requires
//! it: DELTAZ_REQUIRE).

use crate::station::{fixture, station};
use fantoccini::{Client, ClientBuilder, Locator};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const CHROMIUM: &str = "/usr/bin/chromium";
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// chromedriver, ended when dropped.
struct Driver(Child);

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts chromedriver on a free port of this computer; its URL.
fn driver() -> (Driver, String) {
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new(CHROMEDRIVER)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "chromedriver did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    (Driver(child), format!("http://127.0.0.1:{port}"))
}

/// The text of element `id`, polled until `done` holds (at most `seconds`).
async fn wait_text(c: &Client, id: &str, seconds: u64, done: impl Fn(&str) -> bool) -> String {
    let start = Instant::now();
    loop {
        let text = c.find(Locator::Id(id)).await.unwrap().text().await.unwrap();
        if done(&text) {
            return text;
        }
        assert!(
            start.elapsed() < Duration::from_secs(seconds),
            "#{id} after {seconds} s: {text:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn screenshots() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .unwrap()
        .join("station-screenshots");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

async fn shoot(c: &Client, id: &str) {
    let png = c
        .find(Locator::Id(id))
        .await
        .unwrap()
        .screenshot()
        .await
        .unwrap();
    assert!(png.starts_with(b"\x89PNG"), "{id}: not a PNG");
    std::fs::write(screenshots().join(format!("{id}.png")), png).unwrap();
}

#[test]
fn the_page_shows_live_points_and_surface_and_captures_in_a_real_browser() {
    let available = Path::new(CHROMIUM).exists() && Path::new(CHROMEDRIVER).exists();
    if !deltaz_testkit::require(
        "chromium",
        available,
        "apt-get install chromium chromium-driver",
    ) {
        return;
    }
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let s = station(&f.dir.join("frames"), &data, &[]);
    let (_driver, url) = driver();
    let profile = dir.path().join("chromium-profile");
    let mut caps = serde_json::Map::new();
    caps.insert(
        "goog:chromeOptions".into(),
        serde_json::json!({
            "binary": CHROMIUM,
            "args": [
                "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                format!("--user-data-dir={}", profile.display()), "--window-size=1400,3200",
            ],
        }),
    );
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async {
        let connector = hyper_util::client::legacy::connect::HttpConnector::new();
        let c = ClientBuilder::new(connector)
            .capabilities(caps)
            .connect(&url)
            .await
            .unwrap();
        c.goto(&format!("http://{}/", s.addr)).await.unwrap();
        // Live: points, and the dots drawn over the frame.
        let points = wait_text(&c, "live-points", 60, |t| t.parse::<u32>().is_ok_and(|n| n > 0)).await;
        let dots: u32 = wait_text(&c, "live-dots", 5, |t| t.parse::<u32>().is_ok()).await.parse().unwrap();
        assert!(points.parse::<u32>().unwrap() <= dots);
        wait_text(&c, "device-status", 10, |t| t == "device: answering").await;
        wait_text(&c, "device-fingerprint", 10, |t| t.len() == 16).await;
        // Surface: the topography and the rotation profile, drawn from the station's figures.
        c.wait()
            .at_most(Duration::from_secs(60))
            .for_element(Locator::Css("#surface-rotation svg"))
            .await
            .unwrap();
        c.find(Locator::Css("#surface-topography svg")).await.unwrap();
        let levels = c.find(Locator::Id("surface")).await.unwrap().attr("data-levels").await.unwrap();
        assert!(levels.unwrap().parse::<u32>().unwrap() >= 2);
        // The levels where the symmetry line was not found are stated, only where there are.
        let surface = c.find(Locator::Id("surface")).await.unwrap();
        let left_out = surface.attr("data-left-out").await.unwrap().unwrap();
        let line = c.find(Locator::Id("surface-note")).await.unwrap();
        let stated = line.is_displayed().await.unwrap()
            && line.text().await.unwrap().contains(&format!("not found at {left_out} of"));
        assert_eq!(stated, left_out != "0", "{left_out} levels left out");
        wait_text(&c, "live-latency", 10, |t| t.ends_with(" ms")).await;
        shoot(&c, "live").await;
        shoot(&c, "surface").await;
        // The operator is told how the subject stands (the real backs' stance limit).
        let stance = c.find(Locator::Id("capture-stance")).await.unwrap();
        assert!(stance.is_displayed().await.unwrap());
        assert!(stance.text().await.unwrap().contains("3.5°"));
        // Capture twice, then compare the two sessions.
        c.find(Locator::Id("subject")).await.unwrap().send_keys("s1").await.unwrap();
        let mut sessions = Vec::new();
        for k in 0..2 {
            c.find(Locator::Id("capture-button")).await.unwrap().click().await.unwrap();
            let message = wait_text(&c, "capture-message", 120, |t| {
                t.starts_with("saved session") || t.starts_with("not captured")
            })
            .await;
            assert!(message.starts_with("saved session"), "{message}");
            let name = c.find(Locator::Id("capture")).await.unwrap().attr("data-session").await.unwrap().unwrap();
            // The levels where the session's symmetry line was not found are told, if any.
            let analysis = std::fs::read_to_string(data.join("s1").join(&name).join("analysis.json")).unwrap();
            let analysis: serde_json::Value = serde_json::from_str(&analysis).unwrap();
            let left_out = analysis["levels_left_out"].as_array().unwrap().len();
            assert_eq!(message.contains("not found at"), left_out > 0, "{message}");
            if k == 0 {
                // The message stays until the next capture: clear it to see the next one.
                c.execute("document.getElementById('capture-message').textContent = ''", vec![]).await.unwrap();
                tokio::time::sleep(Duration::from_millis(1100)).await;
            }
            sessions.push(name);
        }
        assert_ne!(sessions[0], sessions[1]);
        c.find(Locator::Id("compare-button")).await.unwrap().click().await.unwrap();
        let compared = wait_text(&c, "compare-message", 30, |t| !t.is_empty()).await;
        assert!(compared.contains("surface rotation changed beyond the noise"), "{compared}");
        let rows = c.find_all(Locator::Css("#comparison tr")).await.unwrap();
        assert!(rows.len() >= 5, "{} rows", rows.len());
        shoot(&c, "capture").await;
        shoot(&c, "calibration").await;
        let png = c.screenshot().await.unwrap();
        std::fs::write(screenshots().join("page.png"), png).unwrap();
        let latencies = c.execute("return window.stationLatencies", vec![]).await.unwrap();
        let mut latencies: Vec<f64> = latencies.as_array().unwrap().iter().filter_map(|v| v.as_f64()).collect();
        latencies.sort_by(f64::total_cmp);
        eprintln!(
            "station in Chromium: {} frames drawn, latency frame read → page drawn: median {:.0} ms, largest {:.0} ms",
            latencies.len(),
            latencies[latencies.len() / 2],
            latencies[latencies.len() - 1]
        );
        // Before a wall, the page lists it under the surface, left out.
        let walled = station(&f.dir.join("walled"), &dir.path().join("walled-data"), &[]);
        c.goto(&format!("http://{}/", walled.addr)).await.unwrap();
        // Read fresh each time (each surface event replaces the list); WebDriver gives a
        // hidden element's text as empty, so the text found is displayed.
        wait_text(&c, "surface-notes", 60, |t| t.contains("a plane larger than the back left out")).await;
        wait_text(&c, "surface-measures", 5, |t| t.contains("points apart from it, left out")).await;
        let png = c.find(Locator::Id("surface")).await.unwrap().screenshot().await.unwrap();
        std::fs::write(screenshots().join("surface-wall.png"), png).unwrap();
        c.close().await.unwrap();
        check_session(&data.join("s1").join(&sessions[0]), &f.dir.join("system.json"));
    });
}

/// A session's files, and its analysis as `deltaz analyse back` gives it for its clouds.
fn check_session(folder: &Path, system: &Path) {
    let session: serde_json::Value =
        serde_json::from_slice(&std::fs::read(folder.join("session.json")).unwrap()).unwrap();
    assert_eq!(session["format"], "deltaz.session/1");
    assert_eq!(session["subject"], "s1");
    let facts: serde_json::Value = serde_json::from_slice(&std::fs::read(system).unwrap()).unwrap();
    assert_eq!(session["fingerprint"], facts["fingerprint"]);
    let frames = session["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 5, "the burst");
    let centroids = std::fs::read_to_string(folder.join("centroids.csv")).unwrap();
    let dots: u64 = frames.iter().map(|f| f["dots"].as_u64().unwrap()).sum();
    assert_eq!(
        centroids.lines().count() as u64,
        dots + 1,
        "one line per dot"
    );
    assert!(centroids.starts_with("frame,label,col,row,state,ray\n"));
    let identified = centroids
        .lines()
        .filter(|l| l.contains(",identified,"))
        .count() as u64;
    let points: u64 = frames.iter().map(|f| f["points"].as_u64().unwrap()).sum();
    assert!(
        identified >= points * 9 / 10 && identified <= points,
        "{identified} of {points}"
    );
    let mut args: Vec<String> = vec!["analyse".into(), "back".into()];
    for f in frames {
        let cloud = f["cloud"].as_str().unwrap();
        assert!(folder.join(cloud).is_file(), "{cloud}");
        args.extend(["--cloud".into(), cloud.into()]);
    }
    let out_dir = tempfile::tempdir().unwrap();
    args.extend(["--system".into(), system.display().to_string()]);
    args.extend([
        "--out".into(),
        out_dir.path().display().to_string(),
        "--quiet".into(),
    ]);
    let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(&args)
        .current_dir(folder)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in ["analysis.json", "report.html"] {
        assert!(
            std::fs::read(folder.join(name)).unwrap()
                == std::fs::read(out_dir.path().join(name)).unwrap(),
            "{name} differs from deltaz analyse back's"
        );
    }
}
