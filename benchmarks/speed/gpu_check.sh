#!/usr/bin/env bash
# The GPU checks of issues #30 and 40, as one script for a machine with a CUDA device. Run
# from the repository root in an environment with a CUDA build of torch and the project
# installed (pip install -e ".[test]"); results go to $OUT (default: ./gpu_check_out).
# Parts (all by default, about 15 minutes on one H200; name some to run only those, e.g.
# `bash benchmarks/speed/gpu_check.sh probe` within a 10-minute call):
#   tests       the compile and graph-safety tests, on the GPU machine;
#   runs        budget=smoke runs of iql, dual and calql with device=cuda
#               compile.cudagraphs=true (each update replayed as a CUDA graph) and the same
#               runs eager, scores side by side;
#   throughput  benchmarks/speed/gpu_throughput.py --quick (eager, compile, CUDA graphs; JSON);
#   probe       benchmarks/speed/e2e_probe.py: the recipe end to end on a stand-in AntMaze
#               data set at budget=paper sizes (device=cuda compile.cudagraphs=true
#               collector.num_envs=16, about 3 minutes; eager if the CUDA-graph run fails),
#               budget=paper projected from its measured figures only (probe_<mode>.json),
#               merged into the throughput JSON when there is one.
set -u
OUT=${OUT:-gpu_check_out}
PARTS=${*:-tests runs throughput probe}
mkdir -p "$OUT"
python -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.__version__, torch.cuda.get_device_name())" || exit 2

tests() {
  timeout 120 python -m pytest -q -p no:cacheprovider tests/recipe/test_graph_safe_updates.py \
    tests/test_compile.py tests/modules/test_acting_device.py 2>&1 | tail -3 | tee "$OUT/tests.txt"
}

runs() {
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
}

throughput() {
  timeout 240 python -m benchmarks.speed.gpu_throughput --device cuda --quick \
    --json "$OUT/gpu_throughput.json" 2>&1 | grep -v Warning | tail -25 | tee "$OUT/throughput.txt"
}

probe() {
  for mode in cudagraphs eager; do
    flag=$([ "$mode" = cudagraphs ] && echo "--cudagraphs" || echo "")
    start=$SECONDS
    timeout 360 python -m benchmarks.speed.e2e_probe --device cuda $flag --num-envs 16 \
      --data "$OUT/probe_data" --json "$OUT/probe_${mode}.json" > "$OUT/probe_${mode}.log" 2>&1
    rc=$?
    echo "e2e probe $mode: exit $rc, $((SECONDS - start)) s" | tee -a "$OUT/probe.txt"
    tail -12 "$OUT/probe_${mode}.log" | tee -a "$OUT/probe.txt"
    if [ $rc -eq 0 ]; then
      if [ -f "$OUT/gpu_throughput.json" ]; then
        python -m benchmarks.speed.gpu_throughput --merge "$OUT/gpu_throughput.json" \
          --probe "$OUT/probe_${mode}.json" --json "$OUT/gpu_throughput_with_probe.json" | tail -12
      fi
      break
    fi
  done
}

for part in $PARTS; do
  case $part in
    tests|runs|throughput|probe) $part ;;
    *) echo "error: unknown part '$part' (tests, runs, throughput, probe)"; exit 2 ;;
  esac
done
