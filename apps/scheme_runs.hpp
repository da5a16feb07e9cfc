// What the one time loop (apps/run_loop.hpp) needs from each particle scheme, in one small
// adapter per algorithm: ExplicitRun (the explicit scheme, one step per particle step,
// apps/explicit_run.hpp), OrbRun and IslandsRun (one sub-iteration of dt_sp per particle step,
// apps/orb_run.hpp and apps/islands_run.hpp, over what they share in apps/subiterated_run.hpp).
// Each says only what its scheme differs in. The rank count is a runtime property (the
// communicator's size, RankParts::ranks in apps/rank_parts.hpp), not a template parameter: every
// scheme class serves one rank and R alike, so one instantiation per scheme is enough, and the
// branches on it sit outside the schemes' kernels (set-up, checkpoints, run.json), where a
// runtime test costs nothing. One rank takes the one-rank path alone: the serial communicator,
// the scheme built without one (no ghosts, no reductions), the scene's particles as they are.
// What differs with the rank count (the share of a checkpoint's particles, gathering a
// checkpoint, reductions) sits in the adapters too, so that the loop itself reads the same for
// every scheme and rank count.
#pragma once

#include "apps/explicit_run.hpp"
#include "apps/islands_run.hpp"
#include "apps/orb_run.hpp"
