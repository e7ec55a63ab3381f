// The synchronizer under its former name: the class is the library's
// (normal_fusion/synchronizer.h).
#pragma once

#include "normal_fusion/synchronizer.h"

namespace normal_fusion {
namespace node {

using normal_fusion::StampSynchronizer;

}  // namespace node
}  // namespace normal_fusion
