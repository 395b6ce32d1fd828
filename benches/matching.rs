//! Matching a 30-frame window over the 2751-frame playground clip (eq. 11), per metric.
//! `cargo bench --bench matching`

use criterion::{criterion_group, criterion_main, Criterion};
use marionette::formats::{amc, asf};
use marionette::motion::matching::{forward_match, MatchParams, Metric};
use std::hint::black_box;
use std::path::Path;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu").join(name)
}

fn bench_matching(c: &mut Criterion) {
    let s = asf::load(&data("16.asf")).unwrap().skeleton;
    let walk = amc::load(&s, &data("16_15.amc")).unwrap();
    let play = amc::load(&s, &data("01_01.amc")).unwrap();
    let mut group = c.benchmark_group("match_30_over_2751");
    group.sample_size(20);
    for (name, metric) in [
        ("euler", Metric::Euler),
        ("quat", Metric::Quat),
        ("position", Metric::Position),
    ] {
        let params = MatchParams::new(30, metric);
        group.bench_function(name, |b| {
            b.iter(|| black_box(forward_match(&s, &walk, &play, &params).unwrap().best))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_matching);
criterion_main!(benches);
