//! Reading Rust source as text, for the repository's structure tests: the `.rs` files below a
//! folder, and passing over one item (to its `;` or the brace that closes its body).

use std::path::{Path, PathBuf};

/// Every `.rs` file below `dir`, build output (`target/`) aside.
pub(super) fn rust_files(dir: &Path, found: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            if entry.file_name() != "target" {
                rust_files(&path, found);
            }
        } else if path.extension().is_some_and(|e| e == "rs") {
            found.push(path);
        }
    }
}

/// Passes over the rest of the item whose first line is `first`: up to its `;` when it has no
/// body (`mod tests;`), else to the brace that closes its body. Attribute lines before the
/// item's own line are passed over with it.
pub(super) fn skip_item<'a>(first: &'a str, rest: &mut impl Iterator<Item = &'a str>) {
    let mut depth = 0i32;
    let mut opened = false;
    for line in std::iter::once(first).chain(rest) {
        let code = line.split("//").next().unwrap_or_default();
        for c in code.chars() {
            match c {
                '{' => {
                    depth += 1;
                    opened = true;
                }
                '}' => depth -= 1,
                _ => {}
            }
        }
        if (opened && depth <= 0) || (!opened && code.trim_end().ends_with(';')) {
            return;
        }
    }
}

#[test]
fn an_item_is_passed_over_to_its_end_and_no_further() {
    let text = "#[allow(x)]\nmod tests {\n    fn f() { }\n}\nafter\n";
    let mut lines = text.lines();
    if let Some(first) = lines.next() {
        skip_item(first, &mut lines);
    }
    assert_eq!(lines.next(), Some("after"));
    let mut lines = "pub struct Unit;\nafter\n".lines();
    if let Some(first) = lines.next() {
        skip_item(first, &mut lines);
    }
    assert_eq!(lines.next(), Some("after"));
}
