#![no_std]
#![no_main]
// Placeholder until the application lands in this file.
