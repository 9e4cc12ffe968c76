// IFS matrices (recurrent, graph-directed IFS) and the constructive
// operations that combine them (docs/algorithms.md#ifs-matrices-recurrent-ifs;
// docs/ifs_matrices.md).
// An umbrella over the parts, each in its own header:
//  * map_table.h        the table of maps (and compositions) entries index;
//  * ifs_matrix_core.h  IfsMatrix, BoolMatrix, aperiodicity, selections;
//  * matrix_expr.h      expressions over matrices, their expansion, catalog;
//  * component_chain.h  the Markov chain for a selection of components.
// The index conventions are stated in ifs_matrix_core.h.
#pragma once

#include "core/matrix/component_chain.h"
#include "core/matrix/ifs_matrix_core.h"
#include "core/matrix/map_table.h"
#include "core/matrix/matrix_expr.h"
