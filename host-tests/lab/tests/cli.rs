//! The `ssis-lab` command: malformed sessions refused with no model written, and the HTML
//! report of a session's loop rendered by a headless browser.

use std::path::Path;

use ssis_lab::model::{Kind, Model};
use ssis_lab::session::read_session;

mod common;
use common::scratch;

/// (e) malformed sessions: each refused with its own message naming file, line and column;
/// the CLI exits non-zero and writes no model.
#[test]
fn e_malformed_sessions() {
    let dir = scratch("malformed");
    let good = "t_s,fog0_rad_s,fog0_t_degc,psi_rad,lat_rad\n1,1e-5,25,0,0.87\n2,1.1e-5,25,0,0.87\n3,1.2e-5,25,0,0.87\n";
    let model = dir.join("m.v1.toml");
    std::fs::write(&model, Model::new(&[Kind::parse_arg("bias").unwrap()]).to_toml()).unwrap();
    let cases: [(&str, String, &[&str]); 6] = [
        ("bad-number", good.replace("1.1e-5", "1.1e-5x"), &["line 3", "column 2", "`fog0_rad_s`", "not a number"]),
        ("missing-column", good.replace("t_s,", "time,"), &["line 1", "`t_s`", "missing"]),
        ("wrong-units", good.replace("fog0_rad_s", "fog0_deg_h"), &["line 1", "column 2", "`fog0_deg_h`"]),
        ("empty", String::new(), &["line 1", "empty"]),
        (
            "truncated",
            good.trim_end().rsplit_once(',').unwrap().0.to_string(),
            &["line 4", "column 5", "`lat_rad`", "truncated"],
        ),
        ("bad-time", good.replace("\n3,", "\n1.5,"), &["line 4", "column 1", "`t_s`", "time does not increase"]),
    ];
    let mut messages = Vec::new();
    for (name, text, must) in &cases {
        let path = dir.join(format!("{name}.csv"));
        std::fs::write(&path, text).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_ssis-lab"))
            .env_remove("RUST_BACKTRACE")
            .env_remove("RUST_LIB_BACKTRACE")
            .args(["add", "temp_rate", "--model"])
            .arg(&model)
            .arg("--session")
            .arg(&path)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        println!(
            "{name}: exit {:?}: {}",
            out.status.code(),
            err.lines().filter(|l| !l.trim().is_empty()).collect::<Vec<_>>().join(" | ")
        );
        assert!(!out.status.success(), "{name}: exit status 0");
        assert!(err.contains(&path.display().to_string()), "{name}: file not named");
        for m in *must {
            assert!(err.contains(m), "{name}: message lacks `{m}`: {err}");
        }
        assert!(!dir.join("m.v2.toml").exists(), "{name}: a model was written");
        let lib = read_session(&path, None).unwrap_err().to_string();
        assert!(!messages.contains(&lib), "{name}: same message as another case");
        messages.push(lib);
    }
    let leftovers: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(leftovers.len(), cases.len() + 1, "unexpected files: {leftovers:?}");
}

/// Runs `chromium --headless --dump-dom` on `page` with a fresh profile; returns (stdout DOM,
/// stderr log). Killed after 90 s.
fn chromium_dump_dom(chromium: &Path, page: &Path, profile: &Path) -> (String, String) {
    use std::io::Read;
    let mut child = std::process::Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1280,2000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("file://{}", page.display()))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", chromium.display()));
    let (mut out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let mut dom = String::new();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(90);
    let waiter = std::thread::spawn(move || {
        let _ = out.read_to_string(&mut dom);
        dom
    });
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            panic!("chromium did not finish in 90 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let status = child.wait().unwrap();
    let (dom, log) = (waiter.join().unwrap(), reader.join().unwrap());
    assert!(status.success(), "chromium exited with {status}: {log}");
    (dom, log)
}

/// The report of a simulated session's loop (v1, `add temp_rate` → v2), written
/// by the CLI, opened in headless Chromium (Debian's `chromium`): no console message at all
/// (the page has no scripts; an error, a failed load or an exception would be logged), and
/// every table and every inline SVG is in the DOM and laid out with a size. The layout is
/// read by a small script the test appends to a copy of the page (the page itself is first
/// checked to have no script and no external reference). Without /usr/bin/chromium the test
/// fails when `CI` is set and is skipped otherwise.
#[test]
fn f_report_renders_in_headless_chromium() {
    let chromium = Path::new("/usr/bin/chromium");
    if !chromium.exists() {
        if std::env::var_os("CI").is_some() {
            panic!("/usr/bin/chromium is missing (CI is set): install Debian's `chromium` package");
        }
        println!("SKIPPED: /usr/bin/chromium is missing (apt-get install -y chromium); set CI to make this a failure");
        return;
    }
    let dir = scratch("report");
    let lab = |args: &[&str]| {
        let out =
            std::process::Command::new(env!("CARGO_BIN_EXE_ssis-lab")).current_dir(&dir).args(args).output().unwrap();
        assert!(out.status.success(), "ssis-lab {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    };
    lab(&["simulate", "thermal", "thermal.csv", "--seed", "3"]);
    lab(&["init", "model.v1.toml", "--terms", "bias,scale_factor,misalignment,thermal_t1"]);
    lab(&["add", "temp_rate", "--model", "model.v1.toml", "--session", "thermal.csv"]);
    lab(&["report", "--model", "model.v2.toml", "--session", "thermal.csv", "--out", "report.html"]);
    let page = std::fs::read_to_string(dir.join("report.html")).unwrap();
    // The SVG namespace is a name, not a resource.
    let refs = page.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for bad in ["<script", "src=", "<link", "url(", "@import", "http://", "https://"] {
        assert!(!refs.contains(bad), "the report is not self-contained: it has `{bad}`");
    }
    // Expected content: fit, diagnosis, detectable-size and history tables; the detectable
    // sinusoid amplitude against period (one curve), the history plot, the residuals before
    // and after the one `add` overlaid (a panel per FOG, with the noise floor) and one
    // residual plot per FOG.
    let (tables, svgs) = (4, 1 + 1 + 1 + 4);
    let overlay = page.split("Residuals before and after each add").nth(1).and_then(|r| r.split("</svg>").next());
    let overlay = overlay.expect("the report has no overlay of the residuals before and after the add");
    for must in ["v1 → v2 (+temp_rate)", "FOG0", "FOG3", "floor ±", "v1", "v2"] {
        assert!(overlay.contains(must), "overlay lacks `{must}`");
    }
    let probe = r#"<script>
(function () {
  var r = [];
  document.querySelectorAll('table').forEach(function (t, i) {
    var b = t.getBoundingClientRect();
    r.push('table ' + i + ' ' + Math.round(b.width) + ' ' + Math.round(b.height) + ' ' + t.rows.length);
  });
  document.querySelectorAll('svg').forEach(function (s, i) {
    var b = s.getBoundingClientRect();
    r.push('svg ' + i + ' ' + Math.round(b.width) + ' ' + Math.round(b.height) + ' ' +
      s.querySelectorAll('*').length + ' ' + (s instanceof SVGSVGElement));
  });
  var h = [];
  document.querySelectorAll('h2').forEach(function (e) { h.push(e.textContent); });
  r.push('h2 ' + h.join('|'));
  var pre = document.createElement('pre');
  pre.id = 'layout-check';
  pre.textContent = r.join('\n');
  document.body.appendChild(pre);
})();
</script>
"#;
    let probed = dir.join("report-probed.html");
    std::fs::write(&probed, page.replace("</body></html>", &format!("{probe}</body></html>"))).unwrap();
    let profile = dir.join("chromium-profile");
    let (dom, log) = chromium_dump_dom(chromium, &probed, &profile);
    let console: Vec<&str> =
        log.lines().filter(|l| l.contains(":CONSOLE") || l.contains("Uncaught") || l.contains("SyntaxError")).collect();
    println!("chromium: {} bytes of DOM, {} log lines, console messages: {console:?}", dom.len(), log.lines().count());
    assert!(console.is_empty(), "console messages: {console:#?}");
    let check = dom
        .split_once("<pre id=\"layout-check\">")
        .and_then(|(_, rest)| rest.split_once("</pre>"))
        .map(|(c, _)| c.to_string())
        .unwrap_or_else(|| panic!("the probe did not run: no layout check in the DOM"));
    println!("{check}");
    let lines: Vec<Vec<&str>> = check.lines().map(|l| l.split(' ').collect()).collect();
    let of = |kind: &str| lines.iter().filter(|l| l[0] == kind).cloned().collect::<Vec<_>>();
    let (t, s) = (of("table"), of("svg"));
    assert_eq!(t.len(), tables, "tables in the DOM");
    assert_eq!(s.len(), svgs, "inline SVGs in the DOM");
    for l in &t {
        let (w, h, rows): (f64, f64, usize) = (l[2].parse().unwrap(), l[3].parse().unwrap(), l[4].parse().unwrap());
        assert!(w > 100.0 && h > 20.0 && rows >= 2, "table not laid out or empty: {l:?}");
    }
    assert_eq!(t[0][4], "5", "fit table: header and one row per FOG");
    for (i, l) in s.iter().enumerate() {
        let (w, h, elems): (f64, f64, usize) = (l[2].parse().unwrap(), l[3].parse().unwrap(), l[4].parse().unwrap());
        // The detectable-size chart (the first) is one curve on a grid: fewer elements.
        let least = if i == 0 { 30 } else { 50 };
        assert!(w >= 600.0 && h >= 300.0 && elems > least && l[5] == "true", "SVG not rendered as SVG: {l:?}");
    }
    assert!(page.contains("minimum detectable sinusoid amplitude"), "the detectable-size chart is missing");
    let h2 = check.lines().find_map(|l| l.strip_prefix("h2 ")).unwrap_or("");
    assert_eq!(
        h2, "Fit|Diagnosis|What this session could have shown|History|Residuals before and after each add|Residuals",
        "sections"
    );
}

/// `add` refuses a term that makes the held-out RMS worse (aging on a session without it),
/// exits non-zero and writes no version; with `--force` it writes it.
#[test]
fn add_refuses_a_worse_version() {
    let dir = scratch("worse");
    let lab = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_ssis-lab")).current_dir(&dir).args(args).output().unwrap()
    };
    assert!(lab(&["simulate", "thermal", "th.csv", "--seed", "3", "--no-hidden"]).status.success());
    assert!(lab(&["init", "m.v1.toml", "--terms", "bias,thermal_t1"]).status.success());
    let out = lab(&["add", "aging", "--model", "m.v1.toml", "--session", "th.csv"]);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    println!("add aging: exit {:?}: {}", out.status.code(), err.trim());
    assert!(!out.status.success(), "a worse version was accepted");
    assert!(err.contains("th.csv") && err.contains("worse") && err.contains("°/h"), "message: {err}");
    assert!(!dir.join("m.v2.toml").exists(), "a worse version was written");
    let out = lab(&["add", "aging", "--model", "m.v1.toml", "--session", "th.csv", "--force"]);
    assert!(out.status.success(), "--force: {}", String::from_utf8_lossy(&out.stderr));
    assert!(dir.join("m.v2.toml").exists(), "--force wrote no version");
    // The error fall: the systematic part removed, the residual at averaging times, the
    // Allan deviation before and after.
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    for must in ["systematic part removed", "residual RMS of tau-means", "floor", "m.v2.allan.svg"] {
        assert!(text.contains(must), "add output lacks `{must}`: {text}");
    }
    let svg = std::fs::read_to_string(dir.join("m.v2.allan.svg")).unwrap();
    assert!(svg.contains("FOG3 before") && svg.contains("FOG3 after"), "Allan plot lacks a FOG's curves");
    let hist = std::fs::read_to_string(dir.join("m.history-fogs.svg")).unwrap();
    for must in ["v2 +aging", "white-noise floor", "FOG3"] {
        assert!(hist.contains(must), "history plot lacks `{must}`");
    }
}

/// Runs `ssis-lab` in `dir`: (exit status, stdout + stderr).
fn lab_in(dir: &Path, args: &[&str]) -> (Option<i32>, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_ssis-lab"))
        .current_dir(dir)
        .env_remove("RUST_BACKTRACE")
        .args(args)
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("$ ssis-lab {}\n  exit {:?}\n{text}", args.join(" "), out.status.code());
    (out.status.code(), text)
}

/// A mistyped catalog term is refused at `init` (not written as an expression) with the
/// catalog and the nearest name; at `add` an expression's variables must be columns of the
/// session; nothing is written.
#[test]
fn init_and_add_check_terms_against_the_catalog_and_the_columns() {
    let dir = scratch("terms");
    let (code, text) = lab_in(&dir, &["init", "m.v1.toml", "--terms", "bias,temprate"]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("did you mean `temp_rate`?") && text.contains("thermal_t1, thermal_t2"), "{text}");
    assert!(!dir.join("m.v1.toml").exists(), "a model was written");
    assert_eq!(lab_in(&dir, &["simulate", "thermal", "th.csv", "--seed", "3"]).0, Some(0));
    assert_eq!(lab_in(&dir, &["init", "m.v1.toml", "--terms", "bias,thermal_t1"]).0, Some(0));
    let (code, text) = lab_in(&dir, &["add", "Temp_Rate", "--model", "m.v1.toml", "--session", "th.csv"]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("did you mean `temp_rate`?"), "{text}");
    let (code, text) = lab_in(&dir, &["add", "chamber_rh * 2", "--model", "m.v1.toml", "--session", "th.csv"]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("th.csv: `chamber_rh`") && text.contains("not a column of the session"), "{text}");
    assert!(text.contains("did you mean `chamber_rh_pct`?"), "{text}");
    assert!(!dir.join("m.v2.toml").exists(), "a version was written");
}

/// The second `add` of the same term onto the same version is refused (it would repeat
/// v2), and the lab's own per-FOG history plot is replaced, not left stale.
#[test]
fn add_refuses_a_repeated_version_and_replaces_its_own_plots() {
    let dir = scratch("repeat");
    assert_eq!(lab_in(&dir, &["simulate", "thermal", "th.csv", "--seed", "3"]).0, Some(0));
    assert_eq!(lab_in(&dir, &["init", "m.v1.toml", "--terms", "bias,thermal_t1"]).0, Some(0));
    let (code, text) = lab_in(&dir, &["add", "temp_rate", "--model", "m.v1.toml", "--session", "th.csv"]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("wrote m.history-fogs.svg") && !text.contains("not written"), "{text}");
    let (code, text) = lab_in(&dir, &["add", "temp_rate", "--model", "m.v1.toml", "--session", "th.csv"]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("gives version 2 again") && text.contains("not written"), "{text}");
    assert!(!dir.join("m.v3.toml").exists(), "a repeated version was written");
    let before = std::fs::read(dir.join("m.history-fogs.svg")).unwrap();
    let (code, text) = lab_in(&dir, &["add", "t_times_g", "--model", "m.v2.toml", "--session", "th.csv", "--force"]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("wrote m.history-fogs.svg") && !text.contains("not written"), "{text}");
    assert_ne!(std::fs::read(dir.join("m.history-fogs.svg")).unwrap(), before, "the per-FOG history is stale");
}

/// `export --base cal.toml --toml cal.toml` updates the table in place, as every `ssis-cal
/// --table` does, and prints beside each changed field who had set the value it replaces.
#[test]
fn export_updates_its_base_in_place_with_the_provenance_it_replaces() {
    let dir = scratch("export-in-place");
    for (session, seed, m) in [("a.csv", "3", "m"), ("b.csv", "4", "n")] {
        assert_eq!(lab_in(&dir, &["simulate", "thermal", session, "--seed", seed]).0, Some(0));
        assert_eq!(lab_in(&dir, &["init", &format!("{m}.v1.toml"), "--terms", "bias,thermal_t1"]).0, Some(0));
        let (code, _) = lab_in(&dir, &["add", "temp_rate", "--model", &format!("{m}.v1.toml"), "--session", session]);
        assert_eq!(code, Some(0));
    }
    assert_eq!(lab_in(&dir, &["export", "--model", "m.v2.toml", "--toml", "cal.toml"]).0, Some(0));
    let (code, text) = lab_in(&dir, &["export", "--model", "n.v2.toml", "--base", "cal.toml", "--toml", "./cal.toml"]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("revision 1 → 2") && text.contains("updated ./cal.toml (revision 2)"), "{text}");
    let bias = text.lines().find(|l| l.trim_start().starts_with("fog[0].bias_rad_s")).unwrap_or("");
    assert!(bias.contains("[was set by ssis-lab export from a.csv, model m.v2.toml version 2]"), "{text}");
    let doc = ssis_common::table::read_doc(&dir.join("cal.toml")).unwrap();
    assert_eq!(doc.table.revision, 2);
    assert!(doc.provenance.iter().any(|p| p.session == "b.csv"), "provenance not updated");
}

/// The HTML report on a static chamber session: no empty column or header in the
/// diagnosis, no residual panel for a quantity the session holds constant (ψ and the input
/// rate: named instead), the ANOVA with its degrees of freedom and critical values.
#[test]
fn report_has_no_empty_columns_or_panels_and_a_full_anova() {
    let dir = scratch("report-gaps");
    assert_eq!(lab_in(&dir, &["simulate", "thermal", "th.csv", "--seed", "3"]).0, Some(0));
    assert_eq!(lab_in(&dir, &["init", "m.v1.toml", "--terms", "bias,thermal_t1"]).0, Some(0));
    assert_eq!(lab_in(&dir, &["report", "--model", "m.v1.toml", "--session", "th.csv", "--out", "r.html"]).0, Some(0));
    let html = std::fs::read_to_string(dir.join("r.html")).unwrap();
    assert!(!html.contains("<th></th>") && !html.contains("\"></td>") && !html.contains("<td></td>"), "empty cell");
    assert!(html.contains("significant at 1 %</th>"), "the significance column has no header");
    assert!(html.contains("constant in this session, not plotted: azimuth ψ, °; input rate along the axis, °/s"));
    // Panel captions are SVG text on a line of their own.
    assert!(html.contains(">\nT, °C\n<"), "no panel for the temperature");
    assert!(!html.contains(">\nazimuth ψ, °\n<"), "a panel for the constant azimuth");
    let anova = html.lines().find(|l| l.contains("two-factor ANOVA")).expect("an ANOVA line");
    for must in ["F_G = ", "(ν 2, 4;", "critical 5 % 6.94, 1 % 18.00"] {
        assert!(anova.contains(must), "the ANOVA line lacks `{must}`: {anova}");
    }
}
