#!/bin/sh
# Placeholder sources for the image's dependency layer: an empty file for every target the
# manifests declare (the daemon's library, binary, each [[bench]] and [[test]]; each workspace
# crate's library, and the demo's and the package assets' binaries), so that the build compiles the dependencies alone and the layer is reused until a
# manifest or Cargo.lock changes.
set -eu
mkdir -p src benches tests
echo 'fn main() {}' > src/main.rs
: > src/lib.rs
for crate in crates/*/ demo/ testkit/; do
  mkdir -p "${crate}src"
  : > "${crate}src/lib.rs"
done
echo 'fn main() {}' > demo/src/main.rs
echo 'fn main() {}' > crates/rtu2mqtt-assets/src/main.rs
for bench in $(sed -n '/^\[\[bench\]\]/,/^name/ s/^name = "\(.*\)"$/\1/p' Cargo.toml); do
  echo 'fn main() {}' > "benches/$bench.rs"
done
for test in $(sed -n '/^\[\[test\]\]/,/^name/ s/^name = "\(.*\)"$/\1/p' Cargo.toml); do
  : > "tests/$test.rs"
done
