#!/usr/bin/env bash
# The GPU checks of issue #30, as one script for a machine with a CUDA device (about 10
# minutes on one H200). Run from the repository root in an environment with a CUDA build
# of torch and the project installed (pip install -e ".[test]"); results go to $OUT
# (default: ./gpu_check_out).
#   1. the compile and graph-safety tests, on the GPU machine;
#   2. budget=smoke runs of iql, dual and calql with device=cuda compile.cudagraphs=true
#      (each update replayed as a CUDA graph) and the same runs eager, scores side by side;
#   3. benchmarks/speed/gpu_throughput.py --quick (eager, compile, CUDA graphs; JSON).
set -u
OUT=${OUT:-gpu_check_out}
mkdir -p "$OUT"
python -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.__version__, torch.cuda.get_device_name())" || exit 2
timeout 120 python -m pytest -q -p no:cacheprovider tests/recipe/test_graph_safe_updates.py tests/test_compile.py 2>&1 | tail -3 | tee "$OUT/tests.txt"
for algo in iql dual calql; do
  for mode in eager cudagraphs; do
    flag=$([ "$mode" = cudagraphs ] && echo "compile.cudagraphs=true" || echo "")
    start=$SECONDS
    timeout 150 python -m torchrl_dual.recipe budget=smoke device=cuda algo="$algo" \
      progress=false $flag output_dir="$OUT/runs/${algo}_${mode}" data_cache_dir="$OUT/data" \
      > "$OUT/${algo}_${mode}.log" 2>&1
    rc=$?
    score=$(grep -o 'at the end of the online phase: .*' "$OUT/${algo}_${mode}.log" | tail -1)
    echo "$algo $mode: exit $rc, $((SECONDS - start)) s, $score"
  done
done | tee "$OUT/runs.txt"
timeout 240 python -m benchmarks.speed.gpu_throughput --device cuda --quick --json "$OUT/gpu_throughput.json" 2>&1 | grep -v Warning | tail -25 | tee "$OUT/throughput.txt"
