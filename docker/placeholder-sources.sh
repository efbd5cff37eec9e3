#!/bin/sh
# Placeholder sources for the image's dependency layer: an empty file for every target the
# manifest declares (the library, the binary, each [[bench]] and [[test]]), so that the build
# compiles the dependencies alone and the layer is reused until Cargo.toml or Cargo.lock
# change.
set -eu
mkdir -p src benches tests
echo 'fn main() {}' > src/main.rs
: > src/lib.rs
for bench in $(sed -n '/^\[\[bench\]\]/,/^name/ s/^name = "\(.*\)"$/\1/p' Cargo.toml); do
  echo 'fn main() {}' > "benches/$bench.rs"
done
for test in $(sed -n '/^\[\[test\]\]/,/^name/ s/^name = "\(.*\)"$/\1/p' Cargo.toml); do
  : > "tests/$test.rs"
done
