#!/usr/bin/env bash
# Build, on this machine, what a lent GPU machine needs beside its own image (python 3.12,
# torch with CUDA, numpy, scipy, ...) to run the harness: the simulators and optuna (the
# threshold ablation's trials; not in that image) as wheels in .whl/ and dm-control
# unpacked into .gpusite/ without the assets no task here uses (dog, the
# locomotion walkers, soccer: 100 MB of the 117), so that both fit the 64 MiB a device call
# may carry. Both folders are ignored by git (.git/info/exclude).
# On the lent machine, before a sitting script:
#   python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
#       --target /tmp/site .whl/*.whl && cp -r .gpusite/. /tmp/site/ \
#       && export PYTHONPATH=/tmp/site MUJOCO_GL=disable
# usage: benchmarks/gpu_carry.sh   (from the repository root; needs the package index)
set -eu
wheels="mujoco==3.17.0 gymnasium==1.4.0 farama-notifications==0.0.4 glfw==2.11.0
pyopengl==3.1.10 dm-env==1.6 dm-tree==0.1.10 shimmy==2.0.1
optuna==5.0.0 alembic==1.20.1 mako==1.4.3 sqlalchemy==2.1.9 colorlog==6.12.0"
mkdir -p .whl .gpusite
for exclude in /.whl/ /.gpusite/; do
    grep -qxF "$exclude" .git/info/exclude || echo "$exclude" >> .git/info/exclude
done
platforms=""
for p in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_24_x86_64 \
         manylinux_2_17_x86_64 manylinux2014_x86_64 manylinux1_x86_64; do
    platforms="$platforms --platform $p"
done
# shellcheck disable=SC2086  # the word lists split on purpose
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
    --implementation cp $platforms -d .whl $wheels dm-control==1.0.50
rm -rf .gpusite/dm_control .gpusite/dm_control-*.dist-info
python3 -m zipfile -e .whl/dm_control-1.0.50-py3-none-any.whl .gpusite
rm .whl/dm_control-1.0.50-py3-none-any.whl
rm -rf .gpusite/dm_control/suite/dog_assets .gpusite/dm_control/locomotion/walkers/assets \
    .gpusite/dm_control/locomotion/soccer/assets .gpusite/dm_control/suite/all_domains.png
du -sh .whl .gpusite
