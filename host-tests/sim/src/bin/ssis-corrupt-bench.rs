//! `ssis-corrupt-bench`: corrupted-frame trials through the flight stream decoder
//! (`ssis_sim::corrupt`), for BENCHMARKS.md.
//!
//! `cargo run --release --bin ssis-corrupt-bench -- [TRIALS] [SEED] [THREADS]`
//! (defaults 100,000,000, 1, 1).

use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num =
        |i: usize, d: u64| args.get(i).and_then(|s| s.replace('_', "").parse::<f64>().ok()).map_or(d, |v| v as u64);
    let (n, seed, threads) = (num(0, 100_000_000), num(1, 1), num(2, 1));
    let t0 = Instant::now();
    let r = ssis_sim::corrupt::run_trials_parallel(n, seed, threads);
    let secs = t0.elapsed().as_secs_f64();
    print!("{}", r.table());
    let t = r.total();
    println!(
        "{} trials (seed {seed}, {threads} thread(s)) in {secs:.1} s: {} corrupted frames accepted (rate {:.3e}), \
         next frame lost {}, second frame lost {}, lost without a collision {}, sent frame recovered {}",
        t.trials,
        t.corrupted_accepted,
        t.corrupted_accepted as f64 / t.trials.max(1) as f64,
        t.next_lost,
        t.second_lost,
        t.lost_without_collision,
        t.recovered
    );
}
