//! A refused model or term says its kind ([`ssis_lab::ModelErrorKind`]), so a caller can
//! tell a missing file from a misspelt term or a value out of range without reading the
//! words; the words still name the file.

use ssis_lab::model::{Catalog, Kind, Model};
use ssis_lab::{LabError, ModelErrorKind};

/// The kind of a model refusal, and its message.
fn kind_of(r: Result<impl std::fmt::Debug, LabError>) -> (ModelErrorKind, String) {
    match r {
        Err(LabError::Model(m)) => (m.kind, m.message),
        other => panic!("not a model refusal: {other:?}"),
    }
}

#[test]
fn model_refusals_say_their_kind() {
    let text = Model::new(&[Kind::Catalog(Catalog::Bias)]).to_toml();
    assert!(Model::parse(&text, "m.toml").is_ok());

    let (k, m) = kind_of(Model::read(std::path::Path::new("/nonexistent/m.v1.toml")));
    assert_eq!(k, ModelErrorKind::Io, "{m}");
    assert!(m.contains("/nonexistent/m.v1.toml"), "{m}");

    let (k, m) = kind_of(Model::parse(&text.replacen("ssis-error-model/1", "ssis-error-model/7", 1), "m.toml"));
    assert_eq!(k, ModelErrorKind::Syntax, "{m}");
    assert!(m.starts_with("m.toml: field `format`"), "{m}");

    let (k, m) = kind_of(Model::parse(&text.replacen("\"bias\"", "\"bais\"", 1), "m.toml"));
    assert_eq!(k, ModelErrorKind::Term, "{m}");
    assert!(m.starts_with("m.toml: unknown term `bais`"), "{m}");

    let (k, m) = kind_of(Kind::parse_arg("sin(2*"));
    assert_eq!(k, ModelErrorKind::Term, "{m}");

    let g = text.lines().find(|l| l.starts_with("g_window_s")).expect("the G window line").to_string();
    let (k, m) = kind_of(Model::parse(&text.replacen(&g, "g_window_s = -5.0", 1), "m.toml"));
    assert_eq!(k, ModelErrorKind::Value, "{m}");
    assert!(m.contains("g_window_s"), "{m}");
}
