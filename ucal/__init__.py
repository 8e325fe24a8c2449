"""ucal: calibrate a six-axis robot with the ultrasonic transducer it carries."""

import os

__version__ = "0.1.0"

# ucal's linear algebra is on small matrices (a fit's Jacobian has a few hundred rows and under
# a hundred columns): a BLAS thread pool costs more in waking its threads than it saves, and on
# a busy cell computer it competes with the run's own threads (the state stream, the logger).
# Set only where the user has not chosen, and only before numpy loads.
for _threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")
