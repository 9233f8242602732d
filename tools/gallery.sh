#!/usr/bin/env bash
# Regenerates the scene pictures of docs/gallery.md with the GPU renderer (`treacle render`,
# feature `render`, headless with a Vulkan driver such as lavapipe: mesa-vulkan-drivers).
# Usage: tools/gallery.sh [NAME ...]   (default: all listed; NAME is the picture's name, e.g.
# cube_impact_2 or cube_impact_2-alpha0.15)
# Output: docs/img/gallery/<name>.png; run output under target/gallery/<name>/, its log in
# target/gallery/<name>.log.
#
# Two ways to make a picture (column `via`):
#   run    `treacle run SCENE --frames N`, then `treacle render` of the frame SHOW of the run
#          directory with `--scene SCENE` (colliders, nozzles; scripted collider motion and
#          paths applied, colliders with `remove_at` drawn only before it); the camera frames
#          that frame's particles and the scene's objects.
#          SHOW = `last` takes the last frame written (the runs that stop with a diagnostic).
#          SHOW may list several frames (105,120,135) as in scene mode; the camera is the one
#          that frames the first and the last of them.
#   scene  `treacle render SCENE --frames N` simulates and renders every frame (needed when the
#          simulation moves things the scene file alone cannot place: rigid bodies); the
#          picture is its frame SHOW. The camera frames the
#          initial particles and the scene's objects. SHOW may list several frames (19,26),
#          one picture each, named by the matching entry of a comma-separated suffix list.
# `via` may end in @SIZE/CROP (e.g. run@1920x1080/960x540+420+230): render at SIZE and keep the
# part CROP (WxH+X+Y) with tools/crop_png.py, a zoom for scenes whose colliders are much larger
# than the liquid (the camera frames both).
# Every picture is seen from the default view (iso: from the front right, 25° above the horizon).
set -u
cd "$(dirname "$0")/.."
if [ -z "${NO_BUILD:-}" ]; then
    cargo build --release --quiet --ignore-rust-version --features game,render || exit 1
fi
bin=${TREACLE_BIN:-${CARGO_TARGET_DIR:-target}/release/treacle}
size=${GALLERY_SIZE:-960x540}

# name = scene, or scene-suffix when a suffix is given.
# colour = a `--color` field, optionally @MIN:MAX for a fixed `--range`, optionally /MATERIAL to
#   draw the reconstructed liquid surface instead of the particles (`--material MATERIAL`: honey,
#   chocolate, ketchup, milk, water, or `field` for the colour field on the surface).
# edit = a sed edit applied to a copy of the scene ('_' stands for a space, so match a field
#   name's own underscore with '.' and keep it with a group; `-` = none).
# scene             frames show via   colour                [edit suffix]
list="
cube_impact_1       60     60   run   speed/field
cube_impact_2       12     last run   speed
cube_impact_3       12     last run   speed
cube_impact_4       12     last run   speed
cube_impact_2       12     12   run   speed                 s/anisotropy:_100.0/anisotropy:_0.15/ alpha0.15
cube_impact_3       12     12   run   speed                 s/anisotropy:_100.0/anisotropy:_0.15/ alpha0.15
cube_impact_4       12     12   run   speed                 s/anisotropy:_100.0/anisotropy:_0.15/ alpha0.15
ball_impact         12     last run   speed
ball_impact         60     4,60 run   density@0.95:1.15     s/anisotropy:_100.0/anisotropy:_0.15/;s/\(sound.speed:\)_100.0,/\1_1.0,/ c1-impact,c1-rest
ball_impact         60     4,60 run   density@0.95:1.15     s/anisotropy:_100.0/anisotropy:_0.15/;s/\(sound.speed:\)_100.0,/\1_10.0,/ c10-impact,c10-rest
bunny_impact        30     30   run   speed
bunny_piling        69     30,60,69 run speed/field         - t1,t2,t2.3
stamping_bunny      30     30   run   y
stamping_label      111    86,99,111 run y@0:0.5/field     - pressed,pulling,out
coiling_1           85     85   run   speed/field
coiling_2           85     85   run   speed/field
coiling_3           80     80   run   speed/field           s/dx:_0.00125,/dx:_0.0025,/
buckling_1          97     40,55,70,97 run speed@0:0.3/field - t0.8,t1.1,t1.4,t1.94
buckling_2          89     55,70,89 run speed@0:0.3/field - t1.1,t1.4,t1.78
hourglass_1         30     30   run   speed
hourglass_2         30     30   run   speed
li_armadillos       30     30   run@1920x1080/960x540+420+230 material
li_honey            18     18   run   speed/honey
li_tomatoes         18     18   run   material
li_golf_cornstarch  45     45   scene speed@0:0.01
li_golf_ketchup     45     45   scene speed@0:0.01
li_cow              45     45   run   speed
printing            15     15   run   y
letters             30     19,21,30 run y@0:0.01/field     - printed,t1.05,t1.5
letters             30     21,30 run   y@0:0.01/field      s/\(letters\(.\)mpm\).gcode/\1\21layer.gcode/ 1layer-t1.05,1layer-t1.5
bunny_melting_1     5      5    run   temperature@0:0.2
bunny_melting_2     4      4    run   temperature@0:0.2
li_ice_cream        12     12   run   temperature
"
want=" $* "
echo "$list" | while read -r scene_name frames show via colour edit suffix; do
    [ -z "$scene_name" ] && continue
    name=$scene_name
    [ -n "${suffix:-}" ] && name="$scene_name-$suffix"
    # Several pictures of one run: pictures "frame:name ...", the run named after the first.
    pictures=""
    IFS=, read -r -a shows <<< "$show"
    IFS=, read -r -a suffixes <<< "${suffix:-}"
    if [ ${#shows[@]} -gt 1 ]; then
        name=$scene_name-${suffixes[0]}
        for i in "${!shows[@]}"; do pictures+=" ${shows[$i]}:$scene_name-${suffixes[$i]}"; done
    fi
    if [ $# -gt 0 ] && [[ "$want" != *" $name "* ]]; then
        hit=""
        for p in $pictures; do [[ "$want" == *" ${p#*:} "* ]] && hit=1; done
        [ -n "$hit" ] || continue
    fi
    scene="scenes/$scene_name.ron"
    [ -f "$scene" ] || { echo "$name: no scene file, skipped"; continue; }
    mkdir -p target/gallery docs/img/gallery
    if [ -n "${edit:-}" ] && [ "$edit" != "-" ]; then
        sed "${edit//_/ }" "$scene" > "target/gallery/$name.ron"
        scene="target/gallery/$name.ron"
    fi
    rsize=$size
    crop=""
    if [[ "$via" == *@* ]]; then
        rsize=${via#*@}; crop=${rsize#*/}; rsize=${rsize%%/*}; via=${via%%@*}
    fi
    look=()
    if [[ "$colour" == */* ]]; then
        look=(--material "${colour#*/}"); colour=${colour%%/*}
    fi
    field=${colour%%@*}
    range=()
    [[ "$colour" == *@* ]] && range=(--range "${colour#*@}")
    out="target/gallery/$name"
    rm -rf "$out" "$out.png.d"
    started=$(date +%s)
    if [ "$via" = scene ]; then
        "$bin" render "$scene" --out "$out.png.d" --frames "$frames" --color "$field" \
            "${range[@]}" "${look[@]}" --size "$rsize" > "$out.log" 2>&1
        status=$?
        pngs="$out.png.d"
    else
        "$bin" run "$scene" --out "$out" --frames "$frames" > "$out.log" 2>&1
        status=$?
        picks=()
        if [ "$show" = last ]; then
            picks=("$(ls "$out"/frame_*.ply 2>/dev/null | tail -n 1)")
        else
            for s in "${shows[@]}"; do picks+=("$(printf '%s/frame_%05d.ply' "$out" "$((10#$s))")"); done
        fi
        pngs=""
        if [ -f "${picks[0]}" ]; then
            # A run directory holding only the chosen frames (the camera frames the first and
            # the last).
            mkdir -p "$out/pick"
            for pick in "${picks[@]}"; do
                [ -f "$pick" ] && ln -sf "../$(basename "$pick")" "$out/pick/"
            done
            "$bin" render "$out/pick" --scene "$scene" --out "$out.png.d" --color "$field" \
                "${range[@]}" "${look[@]}" --size "$rsize" >> "$out.log" 2>&1
            pngs="$out.png.d"
            if [ ${#shows[@]} -eq 1 ]; then
                show=$(basename "${picks[0]}" .ply); show=${show#frame_}
            fi
        fi
    fi
    wall=$(( $(date +%s) - started ))
    [ -n "$pictures" ] || pictures="$show:$name"
    for p in $pictures; do
        show=${p%%:*}
        picture=${p#*:}
        if [ "$show" = last ]; then
            png=$(ls "$pngs"/frame_*.png 2>/dev/null | tail -n 1)
        else
            png=$(printf '%s/frame_%05d.png' "$pngs" "$((10#$show))")
        fi
        if [ -n "$pngs" ] && [ -f "$png" ]; then
            if [ -n "$crop" ]; then
                python3 tools/crop_png.py "$png" "docs/img/gallery/$picture.png" "$crop"
            else
                cp "$png" "docs/img/gallery/$picture.png"
            fi
            echo "$picture: exit $status, ${wall} s, $(basename "$png") -> docs/img/gallery/$picture.png"
        else
            echo "$picture: exit $status, ${wall} s, no picture — $(tail -n 2 "$out.log" | tr '\n' ' ' | cut -c1-300)"
        fi
    done
done
