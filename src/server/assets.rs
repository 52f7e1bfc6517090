//! The dashboard's files from `web/`, compiled into the binary so the daemon serves them
//! from anywhere, offline. Add a file here when `web/` gains one (plain files, no build step:
//! `index.html` loads `app.js` as an ES module, which imports the others).

/// One embedded file: URL path, content type, contents.
pub(crate) struct Asset {
    pub path: &'static str,
    pub content_type: &'static str,
    pub body: &'static str,
}

/// JavaScript modules must be served with a JavaScript MIME type, or browsers refuse them.
const JS: &str = "text/javascript; charset=utf-8";

/// Every file the daemon serves; `/` is `index.html`.
pub(crate) const ASSETS: &[Asset] = &[
    Asset {
        path: "/",
        content_type: "text/html; charset=utf-8",
        body: include_str!("../../web/index.html"),
    },
    Asset {
        path: "/style.css",
        content_type: "text/css; charset=utf-8",
        body: include_str!("../../web/style.css"),
    },
    Asset {
        path: "/favicon.svg",
        content_type: "image/svg+xml",
        body: include_str!("../../web/favicon.svg"),
    },
    Asset {
        path: "/app.js",
        content_type: JS,
        body: include_str!("../../web/app.js"),
    },
    Asset {
        path: "/conn.js",
        content_type: JS,
        body: include_str!("../../web/conn.js"),
    },
    Asset {
        path: "/history.js",
        content_type: JS,
        body: include_str!("../../web/history.js"),
    },
    Asset {
        path: "/units.js",
        content_type: JS,
        body: include_str!("../../web/units.js"),
    },
    Asset {
        path: "/plot.js",
        content_type: JS,
        body: include_str!("../../web/plot.js"),
    },
    Asset {
        path: "/spectrum.js",
        content_type: JS,
        body: include_str!("../../web/spectrum.js"),
    },
    Asset {
        path: "/harmonics.js",
        content_type: JS,
        body: include_str!("../../web/harmonics.js"),
    },
    Asset {
        path: "/strip.js",
        content_type: JS,
        body: include_str!("../../web/strip.js"),
    },
    Asset {
        path: "/contrast.js",
        content_type: JS,
        body: include_str!("../../web/contrast.js"),
    },
    Asset {
        path: "/scope.js",
        content_type: JS,
        body: include_str!("../../web/scope.js"),
    },
    Asset {
        path: "/status.js",
        content_type: JS,
        body: include_str!("../../web/status.js"),
    },
    Asset {
        path: "/controls.js",
        content_type: JS,
        body: include_str!("../../web/controls.js"),
    },
    Asset {
        path: "/force.js",
        content_type: JS,
        body: include_str!("../../web/force.js"),
    },
    Asset {
        path: "/image.js",
        content_type: JS,
        body: include_str!("../../web/image.js"),
    },
    Asset {
        path: "/sweeper.js",
        content_type: JS,
        body: include_str!("../../web/sweeper.js"),
    },
    Asset {
        path: "/pids.js",
        content_type: JS,
        body: include_str!("../../web/pids.js"),
    },
];

/// The asset at `path`, if any.
pub(crate) fn find(path: &str) -> Option<&'static Asset> {
    ASSETS.iter().find(|a| a.path == path)
}

#[cfg(test)]
mod tests {
    use super::ASSETS;

    #[test]
    fn assets_are_unique_and_typed() {
        for (i, a) in ASSETS.iter().enumerate() {
            assert!(a.path.starts_with('/'), "{}", a.path);
            assert!(!a.body.is_empty(), "{} is empty", a.path);
            assert!(!a.content_type.is_empty(), "{} has no content type", a.path);
            assert!(
                ASSETS[i + 1..].iter().all(|b| b.path != a.path),
                "{} listed twice",
                a.path
            );
            if a.path.ends_with(".js") {
                assert_eq!(a.content_type, super::JS, "{}", a.path);
            }
        }
    }

    /// Every file index.html links (`href="/…"`, `src="/…"`) is served.
    #[test]
    fn every_link_of_the_page_is_served() {
        let page = ASSETS.iter().find(|a| a.path == "/").expect("index.html");
        for attr in ["href=\"/", "src=\"/"] {
            for part in page.body.split(attr).skip(1) {
                let target = format!("/{}", part.split('"').next().unwrap_or_default());
                assert!(
                    ASSETS.iter().any(|b| b.path == target),
                    "index.html links {target}, which is not in ASSETS"
                );
            }
        }
    }

    /// Every module the page imports is served: a missing entry would break the page.
    #[test]
    fn every_import_is_served() {
        for a in ASSETS.iter().filter(|a| a.path.ends_with(".js")) {
            for line in a.body.lines() {
                let Some(rest) = line.trim().strip_prefix("import ") else {
                    continue;
                };
                let Some(from) = rest.split("from \"./").nth(1) else {
                    continue;
                };
                let target = format!("/{}", from.split('"').next().unwrap_or_default());
                assert!(
                    ASSETS.iter().any(|b| b.path == target),
                    "{} imports {}, which is not in ASSETS",
                    a.path,
                    target
                );
            }
        }
    }
}
