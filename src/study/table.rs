//! The one table writer of `sweep` and `ablate`: CSV by the `csv` crate (its standard quoting: a
//! field is quoted only when it holds a comma, a quote or a line break), JSON by `serde_json`.

use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};

/// The formats a table file can have, chosen by its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Csv,
    Json,
}

impl Format {
    /// `.csv` or `.json`; any other name is an error naming the path.
    pub fn of(path: &Path) -> Result<Self> {
        match path.extension().and_then(|e| e.to_str()) {
            Some("json") => Ok(Format::Json),
            Some("csv") => Ok(Format::Csv),
            _ => Err(Error::output(path, "must end in .csv or .json")),
        }
    }
}

fn table_error(e: impl std::fmt::Display) -> Error {
    Error::Runtime(format!("cannot write the table: {e}"))
}

/// A header and rows of fields, already formatted (numbers as Rust prints them: `30`, `0.1`).
pub fn csv<R: AsRef<[String]>>(header: &[String], rows: &[R]) -> Result<String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(header).map_err(table_error)?;
    for r in rows {
        w.write_record(r.as_ref()).map_err(table_error)?;
    }
    let bytes = w.into_inner().map_err(table_error)?;
    String::from_utf8(bytes).map_err(table_error)
}

/// The rows as an indented JSON array of objects.
pub fn json<T: Serialize + ?Sized>(rows: &T) -> Result<String> {
    serde_json::to_string_pretty(rows).map_err(table_error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_quotes_only_what_needs_it_and_reads_back() {
        let header = ["label".to_string(), "v".to_string()];
        let rows = [
            vec!["walks=5 levels=2".to_string(), "0.1".to_string()],
            vec!["a,b \"c\"".to_string(), "30".to_string()],
        ];
        let text = csv(&header, &rows).unwrap();
        assert_eq!(
            text,
            "label,v\nwalks=5 levels=2,0.1\n\"a,b \"\"c\"\"\",30\n"
        );
        let mut r = csv::Reader::from_reader(text.as_bytes());
        let back: Vec<Vec<String>> = r
            .records()
            .map(|rec| rec.unwrap().iter().map(String::from).collect())
            .collect();
        assert_eq!(back, rows);
    }

    #[test]
    fn format_follows_the_extension() {
        assert_eq!(Format::of(Path::new("a.csv")).unwrap(), Format::Csv);
        assert_eq!(Format::of(Path::new("a.json")).unwrap(), Format::Json);
        assert!(Format::of(Path::new("a.txt")).is_err());
    }
}
