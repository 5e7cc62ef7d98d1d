#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Regenerate the segmentation data, the three models of the paper's Table I and the report.
#
#   bash ros2_ws/train_segmentation.sh [OUT]      (default OUT: out/segmentation)
#
# 1. simulated data (suture-sim --png-dir): 600 + 2000 legacy training images, 20 legacy
#    validation images, 40 on-site fine-tuning images, and the two on-site test sets of 40 images
#    each (Set 1: phantom backgrounds, Set 2: printed surgical scenes), all with different seeds;
# 2. M-oST: every layer trained on the 600 legacy images, then continued twice (train --init)
#    on the 2000 more (IoU on fresh legacy frames 0.815 -> 0.854; the first stage alone is the
#    M-oST of the first Table I reproduction), then once more with --photometric (random white
#    balance, exposure, contrast, tone, focus and noise), so that the extractor M-ToSOT freezes
#    does not key on the legacy colours (M-ToSOT IoU 69.7 / 64.3 without that stage, 75.0 / 66.9
#    with it);
#    M-TOT: every layer trained on the 40 on-site images only (30 epochs: after 10 it still
#    predicted no thread at all, IoU 0);
#    M-ToSOT: M-oST fine-tuned on the same 40 on-site images with the 13-layer extractor frozen,
#    the same 30 epochs (10 epochs, about 5 minutes, already give IoU 74.2 / 66.0);
#    m_onsite: every layer of M-oST fine-tuned on 400 more on-site images (200 frames), then
#    continued on those and 400 more (its last.pt; the validation images only pick best.pt);
#    m_onsite_half (the node's default): m_onsite's half-resolution variant (model.py), its
#    coarser layers copied from m_onsite, every layer trained on the same 800 images (best.pt);
# 3. int8 ONNX exports of M-oST, M-ToSOT, m_onsite and m_onsite_half, calibrated on frames of
#    their training domain;
# 4. Table I, per-image IoU/F1 plot and overlays on both test sets (OUT/report).
#
# On 2 CPU cores this takes about 170 minutes; with DEVICE=cuda a few minutes.
# The shipped weights (src/suture_segmentation/suture_segmentation/weights/) are OUT/m_ost/best.pt,
# OUT/m_tosot/best.pt, OUT/m_onsite/last.pt, OUT/m_onsite_half/best.pt and the four
# OUT/*_int8.onnx of this script.
set -euo pipefail
cd "$(dirname "$0")/.."
bash ros2_ws/setup.sh >/dev/null
OUT=${1:-out/segmentation}
DEVICE=${DEVICE:-cpu}
BIN=.venv/bin
DATA=$OUT/data

simulate() {  # name seed frames domain [background]
    local name=$1 seed=$2 frames=$3 domain=$4 background=${5:-}
    [ -d "$DATA/$name/masks" ] && return
    "$BIN/suture-sim" --topology mixed --frames "$frames" --domain "$domain" --seed "$seed" \
        ${background:+--background "$background"} --png-dir "$DATA/$name" --quiet
}
simulate legacy_train 3001 300 legacy
simulate legacy_train_big 3003 1000 legacy
simulate legacy_val 3002 10 legacy
simulate onsite_train 3101 20 on-site
simulate onsite_set1 3201 20 on-site phantom
simulate onsite_set2 3301 20 on-site printed
simulate onsite_pool 38112 200 on-site
simulate onsite_pool2 38113 200 on-site
if [ ! -d "$DATA/onsite_pool800" ]; then  # both pools, as pool_NAME and pool2_NAME
    for kind in images masks; do
        mkdir -p "$DATA/onsite_pool800/$kind"
        for pool in pool pool2; do
            for file in "$DATA/onsite_$pool/$kind"/*.png; do
                ln -s "$(realpath "$file")" "$DATA/onsite_pool800/$kind/${pool}_$(basename "$file")"
            done
        done
    done
fi

"$BIN/suture-seg" train --images "$DATA/legacy_train/images" --masks "$DATA/legacy_train/masks" \
    --val-images "$DATA/legacy_val/images" --val-masks "$DATA/legacy_val/masks" \
    --epochs 24 --steps-per-epoch 100 --seed 0 --device "$DEVICE" --out "$OUT/m_ost_stage1"
"$BIN/suture-seg" train --init "$OUT/m_ost_stage1/best.pt" \
    --images "$DATA/legacy_train_big/images" --masks "$DATA/legacy_train_big/masks" \
    --val-images "$DATA/legacy_val/images" --val-masks "$DATA/legacy_val/masks" \
    --epochs 20 --steps-per-epoch 100 --lr 1e-3 --seed 1 --threads 1 --device "$DEVICE" --out "$OUT/m_ost_stage2"
"$BIN/suture-seg" train --init "$OUT/m_ost_stage2/last.pt" \
    --images "$DATA/legacy_train_big/images" --masks "$DATA/legacy_train_big/masks" \
    --val-images "$DATA/legacy_val/images" --val-masks "$DATA/legacy_val/masks" \
    --epochs 20 --steps-per-epoch 100 --lr 5e-4 --seed 2 --device "$DEVICE" --out "$OUT/m_ost_stage3"
"$BIN/suture-seg" train --init "$OUT/m_ost_stage3/best.pt" --photometric \
    --images "$DATA/legacy_train_big/images" --masks "$DATA/legacy_train_big/masks" \
    --val-images "$DATA/legacy_val/images" --val-masks "$DATA/legacy_val/masks" \
    --epochs 15 --steps-per-epoch 100 --lr 5e-4 --seed 7 --device "$DEVICE" --out "$OUT/m_ost"
"$BIN/suture-seg" train --images "$DATA/onsite_train/images" --masks "$DATA/onsite_train/masks" \
    --epochs 30 --steps-per-epoch 100 --seed 0 --device "$DEVICE" --out "$OUT/m_tot"
"$BIN/suture-seg" finetune --weights "$OUT/m_ost/best.pt" \
    --images "$DATA/onsite_train/images" --masks "$DATA/onsite_train/masks" \
    --epochs 30 --steps-per-epoch 100 --seed 0 --device "$DEVICE" --out "$OUT/m_tosot"

"$BIN/suture-seg" finetune --weights "$OUT/m_ost/best.pt" --all-layers \
    --images "$DATA/onsite_pool/images" --masks "$DATA/onsite_pool/masks" \
    --loss ce --lr 3e-4 --structure-crops 0.35 --epochs 10 --steps-per-epoch 100 --seed 0 \
    --device "$DEVICE" --out "$OUT/m_onsite_stage1"
"$BIN/suture-seg" train --init "$OUT/m_onsite_stage1/last.pt" \
    --images "$DATA/onsite_pool800/images" --masks "$DATA/onsite_pool800/masks" \
    --val-images "$DATA/onsite_train/images" --val-masks "$DATA/onsite_train/masks" \
    --loss ce --lr 2e-4 --structure-crops 0.35 --epochs 15 --steps-per-epoch 100 --seed 2 \
    --device "$DEVICE" --out "$OUT/m_onsite"
"$BIN/suture-seg" train --init "$OUT/m_onsite/last.pt" --half-resolution \
    --images "$DATA/onsite_pool800/images" --masks "$DATA/onsite_pool800/masks" \
    --val-images "$DATA/onsite_train/images" --val-masks "$DATA/onsite_train/masks" \
    --loss ce --lr 1e-3 --structure-crops 0.35 --epochs 25 --steps-per-epoch 100 --seed 3 \
    --device "$DEVICE" --out "$OUT/m_onsite_half"

"$BIN/suture-seg" export --weights "$OUT/m_ost/best.pt" --int8 \
    --calibration-images "$DATA/legacy_train_big/images" --out "$OUT/m_ost_int8.onnx"
"$BIN/suture-seg" export --weights "$OUT/m_tosot/best.pt" --int8 \
    --calibration-images "$DATA/onsite_train/images" --out "$OUT/m_tosot_int8.onnx"
"$BIN/suture-seg" export --weights "$OUT/m_onsite/last.pt" --int8 \
    --calibration-images "$DATA/onsite_pool/images" --out "$OUT/m_onsite_int8.onnx"
"$BIN/suture-seg" export --weights "$OUT/m_onsite_half/best.pt" --int8 \
    --calibration-images "$DATA/onsite_pool/images" --out "$OUT/m_onsite_half_int8.onnx"

# --no-flip-average: one pass per image, as in the paper's Table I
"$BIN/suture-seg" evaluate --no-flip-average \
    --weights "M-oST=$OUT/m_ost/best.pt,M-TOT=$OUT/m_tot/best.pt,M-ToSOT=$OUT/m_tosot/best.pt" \
    --images "$DATA/onsite_set1/images" --masks "$DATA/onsite_set1/masks" \
    --images "$DATA/onsite_set2/images" --masks "$DATA/onsite_set2/masks" \
    --report "$OUT/report"
