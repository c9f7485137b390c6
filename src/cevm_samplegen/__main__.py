"""``python -m cevm_samplegen OUTDIR [--small] [--seed N] [--consumption MODULE:FUNC]``:
the sample logs; ``python -m cevm_samplegen demo-cycles OUTDIR``: the demo cycles of
``configs/cycles``; ``python -m cevm_samplegen standin-cycles OUTDIR``: the fleet case
study's stand-in cycles; ``python -m cevm_samplegen gtfs-feed OUTDIR``: the sample buses'
timetable (``sample_logs/gtfs``)."""

import sys

from cevm_samplegen import cycles, gtfs, main, standin

if sys.argv[1:2] == ["demo-cycles"]:
    cycles.main(sys.argv[2:])
elif sys.argv[1:2] == ["standin-cycles"]:
    standin.main(sys.argv[2:])
elif sys.argv[1:2] == ["gtfs-feed"]:
    gtfs.main(sys.argv[2:])
else:
    sys.exit(main())
