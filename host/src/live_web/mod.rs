//! The live page (`jdbb record --web`, `jdbb live --web`; issue 18): a web page that shows the
//! test as it runs — D, the sample rate, the loss counters, where the machine is in the plan and
//! the current circle's polar trace — pushed as server-sent events at 10–20 Hz.
//!
//! - [`state`]: what the page shows ([`state::LiveState`], its JSON) and the plan's progress
//!   followed from D ([`state::Tracker`]).
//! - [`feed`]: the recorder's side: takes the samples, publishes the state into a shared
//!   [`feed::Board`] without ever waiting for the page.
//! - [`worker`]: each circle's diagnosis while recording, in a thread of its own.
//! - [`end`]: the end-of-test diagnosis, as `jdbb diagnose --record --plan` gives it.
//! - [`server`]: the HTTP server (axum) serving the page and the event stream, read-only,
//!   on localhost unless told otherwise (then with a token).
//!
//! May use: the plan, the synchronisation, the diagnosis and its summary ([`crate::plan`],
//! [`crate::sync`], [`crate::diagnose`], [`crate::report`]),
//! [`crate::link::stream`]'s samples and counters, [`crate::link::live`]'s rate meter. Prints
//! nothing (the CLI does).
pub mod end;
pub mod feed;
pub mod server;
pub mod state;
pub mod worker;
