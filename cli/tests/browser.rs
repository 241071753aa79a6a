//! Tests that drive a real headless chromium (Debian's `chromium` package) through the Chrome
//! DevTools Protocol. Without chromium they fail, unless BOUNCE_ALLOW_NO_BROWSER=1.
//!
//! This file is the crate root of the `browser` test binary; its modules live in tests/browser/
//! (the crate root's modules resolve next to it, hence the paths).

#[path = "browser/cdp.rs"]
mod cdp;
#[path = "browser/selftest.rs"]
mod selftest;
