//! Campaigns: the file's checks (unknown keys with the nearest name, ranges,
//! distributions), run i as a pure function of (campaign, i) in any order, the undispersed
//! campaign as the simulator's own flight, and a dispersion that reaches its runs.

use ssis_mc::run::{draw, run, RunOutput};
use ssis_mc::{Campaign, Indices};

/// An origin in the scenarios folder (the campaign's text is given, the file need not exist).
fn origin() -> String {
    format!("{}/../scenarios/mc-test.toml", env!("CARGO_MANIFEST_DIR"))
}

/// A campaign on the two-minute QEMU flight with `body` after the top-level keys.
fn text(top: &str, body: &str) -> String {
    format!(
        "format = \"ssis-mc-campaign/1\"\nname = \"t\"\nscenario = \"qemu-flight.toml\"\nruns = 8\nseed = 7\n\
         duration_s = 60\n{top}\n{body}\n[indices]\nfrom_s = 30\n{INDICES}"
    )
}

fn parse(top: &str, body: &str) -> anyhow::Result<Campaign> {
    Campaign::parse(&text(top, body), &origin())
}

fn refused(top: &str, body: &str, needles: &[&str]) {
    let e = format!("{:#}", parse(top, body).expect_err("must be refused"));
    for n in needles {
        assert!(e.contains(n), "`{n}` not in: {e}");
    }
    assert!(e.contains("mc-test.toml"), "the file is named: {e}");
}

const INDICES: &str = "[[indices.index]]\nkind = \"AKE\"\n[[indices.index]]\nkind = \"RKE\"\nwindow_s = 5\n\
                       [[indices.index]]\nkind = \"KDE\"\nwindow_s = 5\nseparation_s = 10\n";

const BIAS_EACH: &str = "[[disperse]]\ntable = \"fog.bias_rad_s\"\ndist = \"normal\"\n";

#[test]
fn unknown_keys_are_refused_with_the_nearest_one() {
    refused("rnus = 3", "", &["unknown field `rnus`", "did you mean `runs`?", "line 7"]);
    refused(
        "",
        "[[disperse]]\ntable = \"fog.bias_rad_s\"\ndist = \"normal\"\nsigam = 1e-7\n",
        &["did you mean `sigma`?"],
    );
    refused(
        "",
        "[[disperse]]\ntable = \"fog.bias_rad_s\"\ndist = \"normel\"\n",
        &["`normel`", "did you mean `normal`?"],
    );
    refused(
        "",
        "[[fault]]\nkind = \"fog-lsot\"\nprobability = 0.1\nwindow_s = [1, 2]\n",
        &["did you mean `fog-lost`?"],
    );
    refused("", "[[disperse]]\ntable = \"fog.bias_rad\"\ndist = \"normal\"\n", &["did you mean `fog.bias_rad_s`?"]);
    refused(
        "",
        "[[disperse]]\nscenario = \"star_tracker.latency\"\ndist = \"uniform\"\nlow = 0\nhigh = 1\n",
        &["disperse[0].scenario", "did you mean `latency_ms`?"],
    );
}

#[test]
fn ranges_and_distributions_are_checked_by_field() {
    refused(
        "",
        "[[fault]]\nkind = \"fog-lost\"\nprobability = 1.5\nwindow_s = [1, 2]\n",
        &["fault[0].probability", "1.5"],
    );
    refused("", "[[fault]]\nkind = \"reset\"\nprobability = 0.1\nwindow_s = [10, 90]\n", &["fault[0].window_s", "60"]);
    refused(
        "",
        "[[fault]]\nkind = \"star-outage\"\nprobability = 0.1\nwindow_s = [10, 20]\n",
        &["duration_s", "required"],
    );
    refused(
        "",
        "[[disperse]]\nscenario = \"star_tracker.latency_ms\"\ndist = \"uniform\"\nlow = 2\nhigh = 1\n",
        &["low < high"],
    );
    refused(
        "",
        "[[disperse]]\nscenario = \"star_tracker.latency_ms\"\ndist = \"normal\"\nsigma = 1\nlow = 0\n",
        &["disperse[0].low", "uniform"],
    );
    refused(
        "",
        "[[disperse]]\ntable = \"fog.scale_factor_error\"\ndist = \"normal\"\n",
        &["disperse[0].sigma", "required"],
    );
    refused("", "[[disperse]]\ntable = \"fog.bias_rad_s\"\ndist = \"normal\"\nsigma = -1\n", &["must be > 0"]);
    refused(
        "",
        "[[disperse]]\ntable = \"fog.bias_rad_s\"\nfogs = [4]\ndist = \"normal\"\n",
        &["disperse[0].fogs", "FOG 4"],
    );
    refused("", &format!("{BIAS_EACH}{BIAS_EACH}"), &["dispersed twice"]);
    let e = format!("{:#}", Campaign::parse(&text("", "").replace("runs = 8", "runs = 0"), &origin()).unwrap_err());
    assert!(e.contains("field `runs` = 0"), "{e}");
    let e =
        format!("{:#}", Campaign::parse(&text("", "").replace("from_s = 30", "from_s = 60"), &origin()).unwrap_err());
    assert!(e.contains("indices.from_s"), "{e}");
}

#[test]
fn the_normalised_campaign_lists_params_and_keys_in_order() {
    let c = parse("", &format!("{BIAS_EACH}[[fault]]\nkind = \"fog-lost\"\nprobability = 0.5\nwindow_s = [40, 50]\n"))
        .unwrap();
    let fogs: Vec<String> = (0..4).map(|i| format!("table.fog[{i}].bias_rad_s")).collect();
    assert_eq!(c.params[..4], fogs[..]);
    assert_eq!(c.params[4..], ["fault[0].fog-lost.occurs", "fault[0].fog-lost.t_s", "fault[0].fog-lost.fog"]);
    assert_eq!(c.index_keys[..3], ["AKE_x", "AKE_y", "AKE_z"]);
    assert_eq!(c.index_keys.len(), 9);
    // The bias's 1σ is the table's (the observer's prior on the drift), in rad/s.
    let sigma = c
        .scenario
        .table
        .observer
        .map_or(ssis::calib::ObserverConfig::PAPER.initial_drift_sigma_deg_h, |o| o.initial_drift_sigma_deg_h)
        / ssis_common::DEG_H_PER_RAD_S;
    assert!(matches!(c.quantities[0].dist, ssis_mc::campaign::Dist::Normal { sigma: s, .. } if s == sigma));
    let json: serde_json::Value = serde_json::from_str(&c.to_json().unwrap()).unwrap();
    assert_eq!(json["runs"], 8);
    let spec: ssis_mc::IndexSpec = serde_json::from_value(json["indices"].clone()).unwrap();
    assert_eq!(spec, c.indices);
}

/// Digests of runs `order` of `c`, by run number.
fn digests(c: &Campaign, order: impl Iterator<Item = u64>) -> Vec<(u64, u64)> {
    let mut v: Vec<(u64, u64)> = order.map(|i| (i, run(c, i, 50).unwrap().digest())).collect();
    v.sort();
    v
}

#[test]
fn run_i_is_the_same_alone_in_a_batch_and_in_reverse() {
    let body = format!(
        "{BIAS_EACH}[[disperse]]\nscenario = \"star_tracker.latency_ms\"\ndist = \"truncated-normal\"\nsigma = 5\n\
         [[fault]]\nkind = \"star-outage\"\nprobability = 0.5\nwindow_s = [35, 50]\nduration_s = 5\n"
    );
    let c = parse("", &body).unwrap();
    let forward = digests(&c, 0..6);
    let reverse = digests(&c, (0..6).rev());
    assert_eq!(forward, reverse);
    // Alone: a campaign read afresh, one run, and the runs of another batch first.
    for i in [4u64, 1] {
        let fresh = parse("", &body).unwrap();
        let _ = run(&fresh, 5, 0).unwrap();
        assert_eq!(run(&fresh, i, 50).unwrap().digest(), forward[i as usize].1, "run {i}");
    }
    // Runs differ from each other (the streams are not one).
    let mut d: Vec<u64> = forward.iter().map(|x| x.1).collect();
    d.dedup();
    assert_eq!(d.len(), 6);
    // The draw does not depend on what else is dispersed: a quantity's stream is its own.
    let bias_only = parse("", BIAS_EACH).unwrap();
    for i in 0..6 {
        assert_eq!(draw(&bias_only, i).unwrap().params[..4], draw(&c, i).unwrap().params[..4]);
    }
}

#[test]
fn with_no_dispersion_every_run_is_the_undispersed_flight() {
    let c = parse("noise = \"fixed\"", "").unwrap();
    // The simulator's own flight of the same scenario (`ssis-sim run`), its errors from
    // `from_s` on, through the same indices.
    let mut sc = c.scenario.clone();
    sc.duration_s = 60.0;
    let (mut t, mut e) = (Vec::new(), Vec::new());
    ssis_sim::harness::run(&sc, |r| {
        if r.t_s >= c.indices.from_s {
            t.push(r.t_s);
            e.push(r.att_err_arcsec);
        }
    })
    .unwrap();
    let flight = Indices::compute(&c.indices, &t, &e);
    assert!(flight.iter().all(|(_, v)| v.is_finite() && *v > 0.0), "{flight:?}");
    for i in [0u64, 3, 7] {
        let r: RunOutput = run(&c, i, 0).unwrap();
        assert!(r.params.is_empty());
        assert_eq!(r.indices.len(), flight.len());
        for ((k, a), (_, b)) in r.indices.iter().zip(&flight) {
            assert_eq!(a.to_bits(), b.to_bits(), "run {i} {k}: {a} against the flight's {b}");
        }
    }
}

#[test]
fn twice_a_fogs_bias_sigma_doubles_its_draws_and_changes_its_runs() {
    let table = parse("", BIAS_EACH).unwrap();
    let sigma = match table.quantities[0].dist {
        ssis_mc::campaign::Dist::Normal { sigma, .. } => sigma,
        d => panic!("{d:?}"),
    };
    let twice = parse(
        "",
        &format!(
            "[[disperse]]\ntable = \"fog[0].bias_rad_s\"\ndist = \"normal\"\nsigma = {}\n\
             [[disperse]]\ntable = \"fog.bias_rad_s\"\nfogs = [1, 2, 3]\ndist = \"normal\"\n",
            2.0 * sigma
        ),
    )
    .unwrap();
    for i in 0..4 {
        let (a, b) = (run(&table, i, 0).unwrap(), run(&twice, i, 0).unwrap());
        let p = |r: &RunOutput, k: &str| r.params.iter().find(|(n, _)| n == k).map(|x| x.1).unwrap();
        assert_eq!(p(&b, "table.fog[0].bias_rad_s"), 2.0 * p(&a, "table.fog[0].bias_rad_s"), "run {i}");
        for f in 1..4 {
            let k = format!("table.fog[{f}].bias_rad_s");
            assert_eq!(p(&a, &k), p(&b, &k), "run {i} {k}");
        }
        assert!(a.indices.iter().zip(&b.indices).any(|(x, y)| x.1 != y.1), "run {i}: FOG0's bias changed nothing");
    }
}

#[test]
fn faults_reach_the_flight() {
    let base = run(&parse("noise = \"fixed\"", "").unwrap(), 0, 0).unwrap();
    let reset = parse(
        "noise = \"fixed\"",
        "[[fault]]\nkind = \"reset\"\nprobability = 1\nwindow_s = [40, 41]\nduration_s = 0.5\n",
    )
    .unwrap();
    let r = run(&reset, 0, 0).unwrap();
    assert_eq!(r.params[0], ("fault[0].reset.occurs".into(), 1.0));
    assert_eq!(base.evaluated - r.evaluated, 100, "0.5 s down at 5 ms: no output for 100 steps");
    let lost =
        parse("noise = \"fixed\"", "[[fault]]\nkind = \"fog-lost\"\nprobability = 1\nwindow_s = [35, 36]\nfog = 2\n")
            .unwrap();
    let r = run(&lost, 0, 0).unwrap();
    assert_eq!(r.params[2], ("fault[0].fog-lost.fog".into(), 2.0));
    assert_ne!(r.indices, base.indices);
    let never =
        parse("noise = \"fixed\"", "[[fault]]\nkind = \"fog-lost\"\nprobability = 0\nwindow_s = [35, 36]\n").unwrap();
    let r = run(&never, 0, 0).unwrap();
    assert_eq!(r.params[0].1, 0.0);
    assert!(r.params[1].1.is_nan());
    assert_eq!(r.indices, base.indices);
}
