//! The programs are the `[[example]]`s beside this crate (see `README.md`);
//! the library is empty.
