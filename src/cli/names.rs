//! Option values that are names from one of the library's tables (the methods, the landmark
//! styles): `--help` lists them from the table itself, and a wrong one gets the library's own
//! message, the same words the service answers with.

use std::marker::PhantomData;
use std::str::FromStr;

use clap::builder::{PossibleValue, TypedValueParser};
use clap::error::ErrorKind;

/// A parser of `T` by its `FromStr`, whose possible values are `(name, help)` pairs.
#[derive(Clone)]
pub struct Names<T> {
    values: Vec<(&'static str, &'static str)>,
    parsed: PhantomData<fn() -> T>,
}

impl<T> Names<T> {
    /// Values named and described by `values` (for `--help`), parsed by `T::from_str`.
    pub fn new(values: impl IntoIterator<Item = (&'static str, &'static str)>) -> Self {
        Names {
            values: values.into_iter().collect(),
            parsed: PhantomData,
        }
    }
}

impl<T> TypedValueParser for Names<T>
where
    T: FromStr + Clone + Send + Sync + 'static,
    T::Err: std::fmt::Display,
{
    type Value = T;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        _arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> Result<T, clap::Error> {
        let text = value.to_str().ok_or_else(|| {
            clap::Error::raw(ErrorKind::InvalidUtf8, "the value is not UTF-8\n").with_cmd(cmd)
        })?;
        text.parse::<T>()
            .map_err(|e| clap::Error::raw(ErrorKind::InvalidValue, format!("{e}\n")).with_cmd(cmd))
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(
            self.values
                .iter()
                .map(|&(name, help)| PossibleValue::new(name).help(help)),
        ))
    }
}
