//! What the tests of planned runs on the G-code machine share (`sync_hidden`, `arc_hidden`,
//! `mechanisms`): the recording read back as `jdbb diagnose --record` reads it, and the names a
//! diagnosis gives. They use the host's reader, which the library of this crate must not: its
//! simulators are written apart from the host.
use jdbb::circular::diagnose::Diagnosis;
use jdbb::circular::model::Path;
use jdbb::circular::plan::{write_program, Dialect as PlanDialect, Plan};
use jdbb::circular::sync::{data_path, synchronise, Record};
use jdbb_tests::gmachine::{Recording, SimConfig, Simulation};

/// The recording as `jdbb record` writes it (CSV in a temporary file) and `diagnose --record`
/// reads it back.
pub fn read_back(rec: &Recording) -> Record {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("rec.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&file).unwrap());
    rec.write_csv(&mut f).unwrap();
    drop(f);
    Record::read(&file).unwrap()
}

/// The machine effects a diagnosis names (not the set-up), in the order selected.
pub fn machine_names(d: &Diagnosis) -> Vec<String> {
    d.effects
        .iter()
        .filter(|f| !f.effect.is_setup())
        .map(|f| f.effect.name())
        .collect()
}

/// The one tolerance rule (`jdbb_tests::tolerance`): within 5 % and within 1 % + 3σ, σ under a
/// stated fraction of the value (10 % unless a test says why more).
// Not every test file that shares this module checks a value.
#[allow(unused_imports)]
pub use jdbb_tests::tolerance::{assert_unbiased, assert_unbiased_sigma};

/// Run `plan`'s LinuxCNC program on the G-code machine as `cfg` sets it up, read the record back
/// (`read_back`), synchronise it from D and cut out the data arcs, as `jdbb diagnose --record
/// --plan` does: the recording (its truth), the data arcs' path and their D (mm).
// Not every test file that shares this module runs a plan this way.
#[allow(dead_code)]
pub fn data_arcs(plan: &Plan, cfg: SimConfig) -> (Recording, Path, Vec<f64>) {
    let rec = Simulation::new(&write_program(plan, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(plan, &r).unwrap();
    let (path, d) = data_path(plan, &r, &sync, [None; 3]).unwrap();
    (rec, path, d)
}
