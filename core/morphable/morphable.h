#pragma once
// Public API of core/morphable: the morphable face model, fitting, texture and the CPU renderer.
#include "core/morphable/builder.h"          // IWYU pragma: export
#include "core/morphable/camera_label.h"     // IWYU pragma: export
#include "core/morphable/fitter.h"           // IWYU pragma: export
#include "core/morphable/measures.h"         // IWYU pragma: export
#include "core/morphable/mesh_renderer.h"    // IWYU pragma: export
#include "core/morphable/morphable_model.h"  // IWYU pragma: export
#include "core/morphable/texture.h"          // IWYU pragma: export
#include "core/morphable/topology.h"         // IWYU pragma: export
