#pragma once
// LibTorch thread configuration. Called once at start-up by every executable.

namespace avatar {

// Chooses the intra-op thread count: `requested` if > 0, else env AVATAR_THREADS if set
// and valid, else all hardware threads. Applies it to LibTorch (and OpenCV) and returns it.
// Throws InvalidOptions for a negative request or a malformed AVATAR_THREADS.
int ConfigureThreads(int requested = 0);

// The count last applied by ConfigureThreads (0 if never called).
int ConfiguredThreads();

}  // namespace avatar
