#pragma once
// LibTorch thread configuration. Called once at start-up by every executable.

namespace avatar {

// Chooses the intra-op thread count: `requested` if > 0, else env AVATAR_THREADS if set
// and valid, else all hardware threads. Applies it to LibTorch (and OpenCV) and returns it.
// Throws InvalidOptions for a negative request or a malformed AVATAR_THREADS.
int ConfigureThreads(int requested = 0);

// The count last applied by ConfigureThreads (0 if never called).
int ConfiguredThreads();

// OpenMP (libgomp, used by LibTorch and OpenBLAS) lets idle threads spin at barriers. When
// other processes compete for the cores (a build, a second job, ctest -j2), a spinning thread
// burns the time slice its partner needs: a render measured 35x slower that way, while with
// passive waiting it ran at the expected speed. libgomp reads OMP_WAIT_POLICY once, when it is
// loaded, so an executable that wants passive waiting must have it in its environment from
// the start. Call this first thing in main(): unless the user set OMP_WAIT_POLICY, it sets it to
// PASSIVE and re-executes the program (same arguments). Returns normally when the variable was
// already set or re-execution failed (the program then runs with the default policy).
void ReexecWithPassiveOpenMpWait(char** argv);

}  // namespace avatar
