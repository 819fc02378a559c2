//! What the examples share: reading rows of numbers (correspondences, points) from text.

use std::path::Path;

/// One row of `N` numbers per line (whitespace- or comma-separated; blank lines and lines
/// starting with `#` are skipped). Errors name the file and line.
pub fn read_numbers<const N: usize>(
    path: &Path,
) -> Result<Vec<[f64; N]>, Box<dyn std::error::Error>> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(str::parse)
            .collect::<Result<_, _>>()
            .map_err(|e| format!("{}:{}: {e}", path.display(), n + 1))?;
        let row: [f64; N] = v.try_into().map_err(|v: Vec<f64>| {
            format!(
                "{}:{}: expected {N} numbers, got {}",
                path.display(),
                n + 1,
                v.len()
            )
        })?;
        rows.push(row);
    }
    Ok(rows)
}

/// One correspondence per line, `sx sy sz tx ty tz`.
#[allow(dead_code)] // each example uses one of the readers
pub fn read_rows(path: &Path) -> Result<Vec<[f64; 6]>, Box<dyn std::error::Error>> {
    read_numbers(path)
}

/// One point per line, `x y z`.
#[allow(dead_code)] // each example uses one of the readers
pub fn read_points(path: &Path) -> Result<Vec<[f64; 3]>, Box<dyn std::error::Error>> {
    read_numbers(path)
}
