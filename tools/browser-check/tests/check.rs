//! Each test writes a small page to a temporary folder and checks it in headless Chromium.
//! Skipped (passing, with a note on stderr) where no Chromium is installed, unless
//! `ASSAY_REQUIRE_CHROMIUM` is set.

use std::path::Path;

use assay_browser_check::{Error, Options, PageCheck, check_file, find_chromium};

/// 1x1 opaque red PNG.
const RED_PIXEL: &str = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8DwHwAFBQIAX8jx0gAAAABJRU5ErkJggg==";

/// False (the test passes as skipped) where no Chromium is installed, unless
/// `ASSAY_REQUIRE_CHROMIUM` is set: then a missing Chromium fails the test.
fn have_chromium() -> bool {
    match find_chromium() {
        Ok(_) => true,
        Err(e) if std::env::var_os("ASSAY_REQUIRE_CHROMIUM").is_some() => panic!("{e}"),
        Err(_) => {
            eprintln!("no Chromium installed (apt-get install chromium): skipped");
            false
        }
    }
}

fn page(dir: &Path, body: &str, icon: bool) -> std::path::PathBuf {
    let icon = if icon {
        r#"<link rel="icon" href="data:,">"#
    } else {
        ""
    };
    let html = format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>Test page</title>{icon}</head>\
         <body>{body}</body></html>"
    );
    let path = dir.join("report.html");
    std::fs::write(&path, html).unwrap();
    path
}

fn check(body: &str) -> PageCheck {
    let dir = tempfile::tempdir().unwrap();
    check_file(&page(dir.path(), body, true), &Options::default()).unwrap()
}

#[test]
fn clean_page_passes_and_screenshots_the_viewport() {
    if !have_chromium() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let body = format!(
        r#"<h1>Report</h1>
        <svg width="200" height="120"><rect width="200" height="120" fill="steelblue"/></svg>
        <img src="data:image/png;base64,{RED_PIXEL}" width="40" height="40" alt="pixel">
        <script>console.log("fine"); console.warn("just a warning");</script>"#
    );
    let shot = dir.path().join("shot.png");
    let options = Options {
        viewport: (640, 480),
        screenshot: Some(shot.clone()),
        ..Options::default()
    };
    let check = check_file(&page(dir.path(), &body, true), &options).unwrap();
    assert!(check.is_clean(), "{:?}", check.problems());
    assert_eq!(check.title, "Test page");
    assert_eq!((check.images, check.broken_images), (1, 0));
    assert_eq!(check.warnings, ["just a warning"]);

    let png = std::fs::read(&shot).unwrap();
    assert_eq!(png.len(), check.screenshot_bytes);
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert_eq!(&png[12..16], b"IHDR");
    let width = u32::from_be_bytes(png[16..20].try_into().unwrap());
    let height = u32::from_be_bytes(png[20..24].try_into().unwrap());
    assert_eq!((width, height), (640, 480));

    let mut reader = png::Decoder::new(std::io::Cursor::new(&png))
        .read_info()
        .unwrap();
    let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
    let frame = reader.next_frame(&mut pixels).unwrap();
    let px = frame.color_type.samples();
    let first = &pixels[..px];
    assert!(
        pixels[..frame.buffer_size()].chunks(px).any(|p| p != first),
        "screenshot is one colour"
    );
}

#[test]
fn full_page_screenshot_covers_the_whole_page() {
    if !have_chromium() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("full.png");
    let options = Options {
        viewport: (400, 300),
        full_page: true,
        screenshot: Some(shot.clone()),
        ..Options::default()
    };
    let body = r#"<div style="height:1000px;background:linear-gradient(red,blue)"></div>"#;
    let check = check_file(&page(dir.path(), body, true), &options).unwrap();
    assert!(check.is_clean(), "{:?}", check.problems());
    let png = std::fs::read(&shot).unwrap();
    let width = u32::from_be_bytes(png[16..20].try_into().unwrap());
    let height = u32::from_be_bytes(png[20..24].try_into().unwrap());
    assert_eq!(width, 400);
    assert!(height >= 1000, "full page screenshot is {width}x{height}");
}

#[test]
fn console_error_fails_naming_the_message() {
    if !have_chromium() {
        return;
    }
    let check = check(r#"<script>console.error("boom", 42);</script>"#);
    assert_eq!(check.console_errors, ["boom 42"]);
    assert!(
        check.exceptions.is_empty()
            && check.failed_requests.is_empty()
            && check.external_requests.is_empty()
    );
    assert!(!check.is_clean());
    assert!(
        check.problems().iter().any(|p| p.contains("boom")),
        "{:?}",
        check.problems()
    );
}

#[test]
fn uncaught_exception_fails() {
    if !have_chromium() {
        return;
    }
    let check = check(r#"<script>throw new Error("kaboom");</script>"#);
    assert_eq!(check.exceptions.len(), 1, "{check:?}");
    assert!(check.exceptions[0].contains("kaboom"), "{check:?}");
    assert!(check.console_errors.is_empty(), "{check:?}");
    assert!(!check.is_clean());
}

#[test]
fn unhandled_rejection_fails() {
    if !have_chromium() {
        return;
    }
    let check = check(r#"<script>Promise.reject(new Error("later"));</script>"#);
    assert!(
        check.exceptions.iter().any(|e| e.contains("later")),
        "{check:?}"
    );
}

/// Port 9 is on Chromium's unsafe-port list: the request fails at once (`ERR_UNSAFE_PORT`)
/// without a connection attempt, so the test needs no network and no closed-port luck.
#[test]
fn request_to_the_network_fails_as_external() {
    if !have_chromium() {
        return;
    }
    let check = check(r#"<img src="http://127.0.0.1:9/x.png">"#);
    assert_eq!(
        check.external_requests,
        ["http://127.0.0.1:9/x.png"],
        "{check:?}"
    );
    assert!(
        check
            .failed_requests
            .iter()
            .any(|r| r.contains("127.0.0.1:9")),
        "{check:?}"
    );
    assert!(!check.is_clean());
}

#[test]
fn missing_local_file_fails_as_failed_request_and_broken_image() {
    if !have_chromium() {
        return;
    }
    let check = check(r#"<img src="missing.png" alt="gone">"#);
    assert_eq!(check.failed_requests.len(), 1, "{check:?}");
    assert!(
        check.failed_requests[0].contains("missing.png"),
        "{check:?}"
    );
    assert!(
        check.failed_requests[0].contains("ERR_FILE_NOT_FOUND"),
        "{check:?}"
    );
    assert_eq!((check.images, check.broken_images), (1, 1));
    assert!(check.external_requests.is_empty(), "{check:?}");
    assert!(!check.is_clean());
}

/// Pins the finding in the crate docs: no favicon request under file:// in headless mode.
#[test]
fn no_favicon_request_without_icon_link() {
    if !have_chromium() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let check = check_file(
        &page(dir.path(), "<p>no icon link</p>", false),
        &Options::default(),
    )
    .unwrap();
    assert!(check.is_clean(), "{:?}", check.problems());
}

#[test]
fn page_that_never_finishes_times_out() {
    if !have_chromium() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = page(dir.path(), "<script>while (true) {}</script>", true);
    let options = Options {
        timeout: std::time::Duration::from_secs(3),
        ..Options::default()
    };
    let started = std::time::Instant::now();
    let check = check_file(&path, &options).unwrap();
    assert!(check.timed_out, "{check:?}");
    assert!(!check.is_clean());
    // The spinning script is terminated: the probes and the screenshot do not wait for it.
    assert!(
        started.elapsed() < std::time::Duration::from_secs(30),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn missing_file_is_an_error() {
    let err = check_file(Path::new("/nonexistent/report.html"), &Options::default()).unwrap_err();
    assert!(matches!(err, Error::Io(..)), "{err}");
}
