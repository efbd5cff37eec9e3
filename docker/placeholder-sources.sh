#!/bin/sh
# Placeholder sources for the image's dependency layer: an empty file for every target the
# manifest declares (the library, the binary, each [[bench]] and [[test]], the wire crate's
# library), so that the build compiles the dependencies alone and the layer is reused until a
# manifest or Cargo.lock changes.
set -eu
mkdir -p src benches tests crates/rtu2mqtt-modbus/src
echo 'fn main() {}' > src/main.rs
: > src/lib.rs
: > crates/rtu2mqtt-modbus/src/lib.rs
for bench in $(sed -n '/^\[\[bench\]\]/,/^name/ s/^name = "\(.*\)"$/\1/p' Cargo.toml); do
  echo 'fn main() {}' > "benches/$bench.rs"
done
for test in $(sed -n '/^\[\[test\]\]/,/^name/ s/^name = "\(.*\)"$/\1/p' Cargo.toml); do
  : > "tests/$test.rs"
done
