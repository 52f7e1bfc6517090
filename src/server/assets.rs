//! The dashboard's files from `web/`, compiled into the binary so the daemon serves them
//! from anywhere, offline. Add a file here when `web/` gains one.

/// One embedded file: URL path, content type, contents.
pub(crate) struct Asset {
    pub path: &'static str,
    pub content_type: &'static str,
    pub body: &'static str,
}

/// Every file the daemon serves; `/` is `index.html`.
pub(crate) const ASSETS: &[Asset] = &[Asset {
    path: "/",
    content_type: "text/html; charset=utf-8",
    body: include_str!("../../web/index.html"),
}];

/// The asset at `path`, if any.
pub(crate) fn find(path: &str) -> Option<&'static Asset> {
    ASSETS.iter().find(|a| a.path == path)
}
