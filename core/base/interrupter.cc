#include "core/base/interrupter.h"

namespace nimbus {

Interrupter& OrNull(Interrupter* i) {
  static Interrupter null_interrupter;
  return i ? *i : null_interrupter;
}

}  // namespace nimbus
