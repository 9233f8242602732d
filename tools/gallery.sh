#!/usr/bin/env bash
# Regenerates the pictures of docs/gallery.md: runs each listed scene for the given number of
# frames (or until it stops with a diagnostic) and draws the last written frame with
# `treacle snapshot`. Usage: tools/gallery.sh [SCENE-NAME ...]   (default: all listed)
# Output: docs/img/gallery/<scene>.png, run output under target/gallery/<scene>/.
set -u
cd "$(dirname "$0")/.."
[ -n "${NO_BUILD:-}" ] || cargo build --release --quiet || exit 1
bin=${TREACLE_BIN:-target/release/treacle}

# scene            frames  view  colour   [sed edit applied to a copy of the scene, name suffix]
list="
cube_impact_1      60      iso   speed
cube_impact_2      12      z     speed
cube_impact_3      12      z     speed
cube_impact_4      12      z     speed
cube_impact_2      12      z     speed    s/anisotropy:_100.0/anisotropy:_0.15/ alpha0.15
cube_impact_3      12      z     speed    s/anisotropy:_100.0/anisotropy:_0.15/ alpha0.15
cube_impact_4      12      z     speed    s/anisotropy:_100.0/anisotropy:_0.15/ alpha0.15
ball_impact        12      z     speed
bunny_impact       30      iso   speed
bunny_piling       60      iso   speed
stamping_bunny     30      iso   y
coiling_1          18      z     speed
coiling_2          18      z     speed
coiling_3          18      z     speed
buckling_1         18      z     speed
buckling_2         18      z     speed
hourglass_1        30      z     speed
hourglass_2        30      z     speed
li_armadillos      30      iso   material
li_honey           18      z     speed
li_tomatoes        18      z     material
li_golf_cornstarch 30      z     material
li_golf_ketchup    30      z     material
li_cow             45      iso   speed
printing           15      iso   y
bunny_melting_1    5       z     temperature
bunny_melting_2    4       z     temperature
li_ice_cream       12      z     temperature
"
want=" $* "
echo "$list" | while read -r name frames view colour edit suffix; do
    [ -z "$name" ] && continue
    if [ $# -gt 0 ] && [[ "$want" != *" $name "* ]]; then continue; fi
    [ -f "scenes/$name.ron" ] || { echo "$name: no scene file, skipped"; continue; }
    scene="scenes/$name.ron"
    mkdir -p target/gallery
    if [ -n "${edit:-}" ]; then
        # '_' stands for a space in the edit column.
        sed "${edit//_/ }" "$scene" > "target/gallery/$name-$suffix.ron"
        scene="target/gallery/$name-$suffix.ron"
        name="$name-$suffix"
    fi
    out="target/gallery/$name"
    rm -rf "$out"
    "$bin" run "$scene" --out "$out" --frames "$frames" > "$out.log" 2>&1
    echo "$name: exit $? — $(tail -n 2 "$out.log" | tr '\n' ' ' | cut -c1-300)"
    last=$(ls "$out"/frame_*.ply 2>/dev/null | tail -n 1)
    [ -n "$last" ] && "$bin" snapshot "$last" --out "docs/img/gallery/$name.png" --view "$view" --color "$colour"
done
