//! Tests that drive a real headless chromium (Debian's `chromium` package) through the Chrome
//! DevTools Protocol. Without chromium they fail, unless BOUNCE_ALLOW_NO_BROWSER=1.
//!
//! This file is the crate root of the `browser` test binary; its modules live in tests/browser/
//! (the crate root's modules resolve next to it, hence the paths).

#[path = "browser/cdp.rs"]
mod cdp;
mod common;
#[path = "browser/fixture.rs"]
mod fixture;
#[path = "browser/probes.rs"]
mod probes;
#[path = "browser/selftest.rs"]
mod selftest;
#[path = "browser/viewer.rs"]
mod viewer;
#[path = "browser/xr.rs"]
mod xr;

/// A launched chromium, or `None` where BOUNCE_ALLOW_NO_BROWSER=1 allows going without.
async fn browser() -> Option<cdp::Browser> {
    cdp::chromium_or_skip()?;
    Some(cdp::Browser::launch().await.expect("chromium launches"))
}
