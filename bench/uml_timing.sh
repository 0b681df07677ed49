#!/bin/bash
# Timing of the live service on real SocketCAN vcan0 inside user-mode Linux (SPEC section 6):
# `lde run` and `lde sim` as two processes, candump watching, for DURATION simulated seconds.
#
#   bash tests/uml/run_in_uml.sh --timeout 600 bash bench/uml_timing.sh OUTDIR [DURATION]
#   python bench/uml_timing_report.py OUTDIR
#
# The simulator runs at SCHED_FIFO 90 (above the service's 80: it stands for ECUs with CPUs of
# their own), the service with --realtime --spin-us 0 (see docs/design/service.md for why).
set -u
out=${1:?usage: uml_timing.sh OUTDIR [DURATION]}
dur=${2:-66}
py=${PYTHON:-python}
mkdir -p "$out" && cd "$out" || exit 1
rm -f service.mcap dump.log
candump -L -r 16777216 vcan0 > dump.log &
cd_pid=$!
"$py" -m lde run -i socketcan -c vcan0 --backend fixed --realtime --spin-us 0 --record service.mcap \
    --log-period 30 > run.out 2>&1 &
sv_pid=$!
for _ in $(seq 100); do
    [ -s service.mcap ] && [ "$(stat -c %s service.mcap)" -gt 4096 ] && break
    sleep 0.2
done
"$py" -m lde sim -i socketcan -c vcan0 --scenario heavy_load --seed 3 --duration "$dur" --rt-priority 90 \
    > sim.out 2>&1
kill -TERM "$sv_pid"; wait "$sv_pid"
kill "$cd_pid"
